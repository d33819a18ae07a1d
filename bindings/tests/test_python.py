"""livegesture_runtime against `livegesture generate`: whole inputs and chunked streams give the CLI's
frames bit for bit (both families on their tiny test bundles, both backends; models/default once); the GIL
is released while the runtime computes; bad input raises with the CLI's message; a panic becomes an
exception (docs/python.md)."""
import ast
import math
import os
import pathlib
import shutil
import sys
import threading

import numpy as np
import pytest

from conftest import BACKENDS, ROOT, TINY, assert_same, cli_options, concat

CASES = [(f, b) for f in TINY for b in BACKENDS]
# irregular chunk sizes, cycled (a push may complete no frame, or several)
CHUNKS = [1000, 37, 4801, 1, 2999, 160]


def chunked_push(stream, pcm, rate):
    parts, i, k = [], 0, 0
    while i < len(pcm):
        n = CHUNKS[k % len(CHUNKS)]
        parts.append(stream.push(pcm[i : i + n], sample_rate=rate))
        i, k = i + n, k + 1
    parts.append(stream.finish())
    return concat(parts)


def test_assert_same_can_fail(clips, models):
    """The comparison the checks below use fails on one changed bit, a missing frame or a wrong dtype."""
    wav, _ = clips[16000]
    ref = models("livegesture", "tract").generate(str(wav), seed=7)
    assert_same(ref, ref)
    for change in ("bit", "frame", "dtype"):
        bad = {k: (v.copy() if v is not None else None) for k, v in ref.items()}
        if change == "bit":
            bad["expressions"].view(np.uint32)[3, 7] ^= 1
        elif change == "frame":
            bad = {k: (v[:-1] if v is not None else None) for k, v in bad.items()}
        else:
            bad["poses"] = bad["poses"].astype(np.float64)
        with pytest.raises(AssertionError):
            assert_same(bad, ref)


@pytest.mark.parametrize("family,backend", CASES)
def test_generate_equals_cli(family, backend, models, cli, clips):
    bundle, extra = TINY[family]
    model = models(family, backend)
    assert model.family == family and model.backend == backend and model.fps == 30
    opts = cli_options(extra)
    for rate in (16000, 22050):
        wav, pcm = clips[rate]
        ref = cli.generate(wav, bundle, backend, 7, extra)
        assert len(ref["poses"]) == math.ceil(len(pcm) * 30 / rate)
        assert_same(model.generate(str(wav), seed=7, **opts), ref)
        # the same samples as an array: int16, and float32 (x / 32768, as the WAV reader converts)
        assert_same(model.generate(pcm, sample_rate=rate, seed=7, **opts), ref)
        assert_same(model.generate(pcm.astype(np.float32) / 32768, sample_rate=rate, seed=7, **opts), ref)
    assert_same(model.generate(pathlib.Path(wav), seed=7, **opts), ref)
    # the comparison can fail: another seed gives other motion
    other = model.generate(str(wav), seed=8, **opts)
    assert not np.array_equal(other["poses"], ref["poses"])


@pytest.mark.parametrize("family,backend", CASES)
def test_chunked_push_equals_cli(family, backend, models, cli, clips):
    bundle, extra = TINY[family]
    model = models(family, backend)
    opts = cli_options(extra)
    for rate in (16000, 22050):
        wav, pcm = clips[rate]
        ref = cli.generate(wav, bundle, backend, 3, extra)
        stream = model.stream(seed=3, **opts)
        assert_same(chunked_push(stream, pcm, rate), ref)  # int16 chunks
        assert stream.frames_emitted == len(ref["poses"]) and stream.sample_rate == rate
        # reset: a cold start with the same seed; float32 chunks give the same frames
        stream.reset()
        assert stream.frames_emitted == 0 and stream.sample_rate is None
        assert_same(chunked_push(stream, pcm.astype(np.float32) / 32768, rate), ref)
    # the comparison can fail: another seed
    other = chunked_push(model.stream(seed=4, **opts), pcm, rate)
    assert not np.array_equal(other["poses"], ref["poses"])


def test_default_bundle_equals_cli(lgr, cli, clips, monkeypatch):
    """Model() with no path is models/default (docs/python.md#the-default-bundle); once on tract,
    generate and a push loop equal the CLI's output for that bundle."""
    monkeypatch.delenv("LIVEGESTURE_BUNDLE", raising=False)
    model = lgr.Model()
    assert pathlib.Path(model.path).resolve() == (ROOT / "models/default").resolve()
    assert model.family == "livegesture" and model.backend == "tract"
    wav, pcm = clips[22050]
    ref = cli.generate(wav, ROOT / "models/default", "tract", 7)
    # models/default carries the face channel (docs/face.md): arkit and visemes equal the CLI's npz
    assert model.has_face and ref["arkit"] is not None
    assert_same(model.generate(str(wav), seed=7), ref)
    assert_same(chunked_push(model.stream(seed=7), pcm, 22050), ref)
    # $LIVEGESTURE_BUNDLE names another default
    monkeypatch.setenv("LIVEGESTURE_BUNDLE", str(TINY["diffsheg"][0]))
    assert lgr.Model().family == "diffsheg"


def runs_python_beside(call):
    """Whether the main thread ran Python code while `call()` was running on another thread.

    With a switch interval far longer than the test, a thread that holds the GIL keeps it until it blocks
    or releases it: the main thread (waiting for the GIL) runs before `call` returns only if `call`
    releases the GIL. A call that never releases it never answers True. One that does may still answer
    False when it is short: the GIL is back with the worker before the OS wakes the main thread (seen in CI
    for a `finish()` of one token on a loaded machine), so callers ask a few times (`releases_the_gil`)."""
    state = {"done": False}
    started = threading.Event()

    def work():
        started.set()
        call()
        state["done"] = True

    old = sys.getswitchinterval()
    sys.setswitchinterval(1000.0)
    try:
        t = threading.Thread(target=work)
        t.start()
        started.wait()  # blocks (GIL released) until work() runs; then waits for the GIL
        ran_beside = not state["done"]
        t.join()
    finally:
        sys.setswitchinterval(old)
    assert state["done"]
    return ran_beside


def releases_the_gil(make_call, tries=5):
    """`runs_python_beside` of a fresh `make_call()` until one answers True (at most `tries`)."""
    return any(runs_python_beside(make_call()) for _ in range(tries))


def test_compute_releases_the_gil(models, lgr, clips):
    model = models("livegesture", "tract")
    _, pcm = clips[16000]

    def pushed():
        stream = model.stream(seed=1)
        stream.push(pcm, 16000)
        return stream.finish

    assert releases_the_gil(lambda: lambda: model.generate(pcm, sample_rate=16000, seed=0))
    assert releases_the_gil(lambda: lambda: model.stream(seed=1).push(pcm, 16000))
    assert releases_the_gil(pushed)
    assert releases_the_gil(lambda: lambda: lgr.Model(TINY["diffsheg"][0]))
    # the check can fail: Python code holds the GIL while it runs, in every try
    assert not releases_the_gil(lambda: lambda: sum(i * i for i in range(200_000)))


def test_streams_on_threads_equal_sequential(models, clips):
    """Streams on several threads at once (each push releases the GIL), and one stream moved between
    threads, give the frames of sequential runs."""
    _, pcm = clips[22050]
    for family in TINY:
        model = models(family, "tract")
        opts = cli_options(TINY[family][1])
        want = {s: chunked_push(model.stream(seed=s, **opts), pcm, 22050) for s in (1, 2, 3)}
        got = {}

        def run(seed):
            got[seed] = chunked_push(model.stream(seed=seed, **opts), pcm, 22050)

        threads = [threading.Thread(target=run, args=(s,)) for s in want]
        for t in threads:
            t.start()
        for t in threads:
            t.join()
        for s in want:
            assert_same(got[s], want[s])
        assert not np.array_equal(want[1]["poses"], want[2]["poses"])
        # one stream, its pushes alternating between two threads
        stream, parts = model.stream(seed=2, **opts), []
        for i in range(0, len(pcm), 3001):
            t = threading.Thread(target=lambda c=pcm[i : i + 3001]: parts.append(stream.push(c, 22050)))
            t.start()
            t.join()
        parts.append(stream.finish())
        assert_same(concat(parts), want[2])


def test_missing_and_non_wav_files_raise_the_cli_message(models, cli, tmp_path):
    model = models("livegesture", "tract")
    bundle = TINY["livegesture"][0]
    missing = tmp_path / "missing.wav"
    want = cli.error("generate", missing, "-o", tmp_path / "x.npz", "--bundle", bundle)
    with pytest.raises(FileNotFoundError) as e:
        model.generate(str(missing))
    assert str(e.value) == want and str(missing) in want
    assert isinstance(e.value, OSError)
    text = tmp_path / "notes.wav"
    text.write_text("this is not audio\n")
    want = cli.error("generate", text, "-o", tmp_path / "x.npz", "--bundle", bundle)
    with pytest.raises(ValueError) as e:
        model.generate(str(text))
    assert str(e.value) == want and "not a WAV file" in want
    assert not (tmp_path / "x.npz").exists()


def test_nan_samples_are_refused_and_the_stream_goes_on(models, clips):
    model = models("livegesture", "tract")
    _, pcm = clips[16000]
    x = pcm.astype(np.float32) / 32768
    bad = x.copy()
    bad[1234] = np.nan
    with pytest.raises(ValueError, match=r"sample 1234 is NaN"):
        model.generate(bad, sample_rate=16000)
    s = model.stream(seed=3)
    first = s.push(x[:5000], 16000)
    bad_chunk = x[5000:6000].copy()
    bad_chunk[10] = np.inf
    with pytest.raises(ValueError, match=r"sample 5010 is inf"):
        s.push(bad_chunk, 16000)
    # the refused chunk changed nothing: the rest gives the frames of the clean audio
    rest = s.push(x[5000:], 16000)
    got = concat([first, rest, s.finish()])
    assert_same(got, chunked_push(model.stream(seed=3), x, 16000))


def test_wrong_bundles_raise_the_cli_message(lgr, cli, tmp_path, clips):
    wav, _ = clips[16000]
    # a folder that is not a bundle
    empty = tmp_path / "empty"
    empty.mkdir()
    want = cli.error("generate", wav, "-o", tmp_path / "x.npz", "--bundle", empty)
    with pytest.raises(FileNotFoundError) as e:
        lgr.Model(empty)
    assert str(e.value) == want and "manifest.json not found" in want
    # a bundle whose graph was changed after export
    broken = tmp_path / "broken"
    shutil.copytree(TINY["diffsheg"][0], broken)
    with open(broken / "denoiser.onnx", "r+b") as f:
        f.seek(100)
        b = f.read(1)
        f.seek(100)
        f.write(bytes([b[0] ^ 0xFF]))
    want = cli.error("generate", wav, "-o", tmp_path / "x.npz", "--bundle", broken)
    with pytest.raises(ValueError) as e:
        lgr.Model(broken)
    assert str(e.value) == want and "sha256 mismatch" in want
    # a manifest that is not JSON
    (broken / "manifest.json").write_text("{ not json")
    want = cli.error("generate", wav, "-o", tmp_path / "x.npz", "--bundle", broken)
    with pytest.raises(ValueError) as e:
        lgr.Model(broken)
    assert str(e.value) == want and "manifest.json" in want
    # a WAV file given as the bundle
    with pytest.raises(OSError, match="manifest.json"):
        lgr.Model(wav)
    with pytest.raises(ValueError, match="unknown backend 'onnx'"):
        lgr.Model(TINY["livegesture"][0], backend="onnx")
    with pytest.raises(ValueError, match="needs backend=\"ort\""):
        lgr.Model(TINY["livegesture"][0], ep="cuda")


def test_bad_options_and_arguments_raise(models, clips):
    lg, ds = models("livegesture", "tract"), models("diffsheg", "tract")
    wav, pcm = clips[16000]
    with pytest.raises(ValueError, match="guidance must be a finite number"):
        lg.stream(guidance=float("nan"))
    with pytest.raises(ValueError, match="temperature must be > 0"):
        lg.stream(temperature=0.0)
    # the option named as the keyword argument, not as a CLI flag
    with pytest.raises(ValueError, match="^ddim_steps only apply to DiffSHEG bundles"):
        lg.stream(ddim_steps=5)
    with pytest.raises(ValueError, match="^temperature, top_k only apply to LiveGesture bundles"):
        ds.stream(temperature=0.5, top_k=3)
    with pytest.raises(ValueError, match="DDIM steps must divide 1000"):
        ds.stream(ddim_steps=7)
    with pytest.raises(ValueError, match="sample_rate is required"):
        lg.generate(pcm)
    with pytest.raises(ValueError, match="whose header gives the rate"):
        lg.generate(str(wav), sample_rate=16000)
    with pytest.raises(ValueError, match="no samples"):
        lg.generate(np.zeros(0, np.float32), sample_rate=16000)
    with pytest.raises(TypeError, match="1-D numpy array"):
        lg.stream().push([0.0, 0.1], 16000)
    with pytest.raises(TypeError, match="WAV file path"):
        lg.generate(12345)
    with pytest.raises(ValueError, match="1-D"):
        lg.stream().push(np.zeros((100, 2), np.float32), 16000)
    with pytest.raises(ValueError, match="dtype int32 is not supported"):
        lg.stream().push(np.zeros(100, np.int32), 16000)
    with pytest.raises(ValueError, match="dtype >f4 is not supported"):
        lg.stream().push(np.zeros(100, ">f4"), 16000)
    with pytest.raises(OverflowError):
        lg.stream(seed=-1)
    s = lg.stream()
    s.push(pcm[:1000], 16000)
    with pytest.raises(ValueError, match="differs from the 16000 Hz"):
        s.push(pcm[1000:2000], 44100)
    with pytest.raises(ValueError, match="sample rate 0 Hz"):
        lg.stream().push(pcm[:100], 0)
    s.finish()
    with pytest.raises(ValueError, match="the stream is finished"):
        s.push(pcm[:100], 16000)
    with pytest.raises(ValueError, match="already finished"):
        s.finish()
    s.reset()
    s.push(pcm[:100], 44100)  # after reset, another rate
    assert s.sample_rate == 44100
    # a strided view is read as its elements
    every_other = np.repeat(pcm[:4000], 2)[::2]
    assert not every_other.flags.c_contiguous
    assert_same(lg.generate(every_other, sample_rate=16000, seed=5),
                lg.generate(np.ascontiguousarray(every_other), sample_rate=16000, seed=5))


def test_a_panic_becomes_a_runtime_error(lgr, models, clips):
    with pytest.raises(RuntimeError, match="internal error .*a deliberate panic"):
        lgr._panic_for_test()
    _, pcm = clips[16000]
    s = models("livegesture", "tract").stream(seed=1)
    s.push(pcm[:1000], 16000)
    with pytest.raises(RuntimeError, match="deliberate panic inside a stream call"):
        lgr._panic_for_test(s)
    # the stream refuses work until reset() (its state may be half-updated)
    with pytest.raises(RuntimeError, match=r"reset\(\) the stream"):
        s.push(pcm[1000:2000], 16000)
    s.reset()
    assert_same(chunked_push(s, pcm, 16000), chunked_push(models("livegesture", "tract").stream(seed=1), pcm, 16000))


def test_an_empty_stream_finishes_with_no_frames(models):
    out = models("livegesture", "tract").stream().finish()
    assert out["poses"].shape == (0, 165) and out["index"].shape == (0,)
    assert out["poses"].dtype == np.float32 and out["index"].dtype == np.int64


def test_stubs_match_the_module(lgr):
    """The installed .pyi names every public class, method and property of the module, and the wheel
    carries py.typed; every public item has a docstring."""
    pkg = pathlib.Path(lgr.__file__).parent
    stubs = [p for p in (pkg / "__init__.pyi", pkg / "livegesture_runtime.pyi") if p.exists()]
    assert stubs, f"no type stubs beside {lgr.__file__}"
    assert (pkg / "py.typed").exists()
    tree = ast.parse(stubs[0].read_text())
    classes = {n.name: {f.name for f in n.body if isinstance(f, ast.FunctionDef)}
               for n in tree.body if isinstance(n, ast.ClassDef)}
    names = {t.id for n in tree.body if isinstance(n, ast.AnnAssign) for t in [n.target]}
    for cls in ("Model", "Stream"):
        public = {a for a in dir(getattr(lgr, cls)) if not a.startswith("_")}
        assert public == classes[cls] - {"__init__"}, cls
        assert getattr(lgr, cls).__doc__
        for a in public:
            assert getattr(getattr(lgr, cls), a).__doc__, f"{cls}.{a} has no docstring"
    module_public = {a for a in dir(lgr) if not a.startswith("_")} - {"livegesture_runtime"}
    assert module_public == (set(classes) - {"Frames"}) | (names - {"__version__"}), module_public
    assert lgr.__doc__ and lgr.__version__ and lgr.FPS == 30 and lgr.POSE_DIM == 165


def test_face_channel_names_and_absence(lgr, models, clips):
    """The face names are docs/face.md's; a bundle without a face graph (the tiny exports) says so
    (has_face False, arkit and visemes None) on stream and generate; the face check can fail."""
    assert lgr.ARKIT_DIM == 52 and len(lgr.ARKIT_NAMES) == 52 and lgr.ARKIT_NAMES[0] == "eyeBlinkLeft"
    assert lgr.ARKIT_NAMES[17] == "jawOpen" and lgr.ARKIT_NAMES[-1] == "tongueOut"
    assert lgr.VISEME_NAMES == ["sil", "PP", "FF", "TH", "DD", "kk", "CH", "SS", "nn", "RR", "aa", "E",
                                "ih", "oh", "ou"] and lgr.VISEME_DIM == 15
    _, pcm = clips[16000]
    for family in TINY:
        m = models(family, "tract")
        assert not m.has_face
        s = m.stream(seed=1)
        got = concat([s.push(pcm, 16000), s.finish()])
        assert got["arkit"] is None and got["visemes"] is None
    # must-fail: face values where the reference has none, none where it has them, out of range, changed
    n = 4
    face = {"arkit": np.full((n, 52), 0.5, np.float32), "visemes": np.full((n, 15), 1 / 15, np.float32)}
    from conftest import assert_same_face
    assert_same_face(face, face, n)
    bad_cases = [(face, {"arkit": None}), ({"arkit": None, "visemes": None}, face)]
    high = {k: v.copy() for k, v in face.items()}
    high["arkit"][1, 24] = 1.5
    bad_cases.append((high, high))
    skew = {k: v.copy() for k, v in face.items()}
    skew["visemes"][2, 0] += 0.1
    bad_cases.append((skew, skew))
    bit = {k: v.copy() for k, v in face.items()}
    bit["arkit"].view(np.uint32)[0, 0] ^= 1
    bad_cases.append((bit, face))
    for got, ref in bad_cases:
        with pytest.raises(AssertionError):
            assert_same_face(got, ref, n)
