"""livegesture_runtime against `livegesture generate`: whole inputs and chunked streams give the CLI's
frames bit for bit (both families, both backends); bad input raises with the CLI's message."""
import ast
import math
import os
import pathlib
import shutil
import threading

import numpy as np
import pytest

from conftest import BACKENDS, FAMILIES, ROOT, assert_same, cli_options, concat, write_wav

CASES = [(f, b) for f in FAMILIES for b in BACKENDS]
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


@pytest.mark.parametrize("family,backend", CASES)
def test_generate_equals_cli(family, backend, models, cli, clips):
    bundle, extra = FAMILIES[family]
    model = models(family, backend)
    assert model.family == family and model.backend == backend
    opts = cli_options(extra)
    wav, pcm = clips[16000]
    ref = cli.generate(wav, bundle, backend, 7, extra)
    assert len(ref["poses"]) == math.ceil(len(pcm) * 30 / 16000)
    assert_same(model.generate(str(wav), seed=7, **opts), ref)
    assert_same(model.generate(pathlib.Path(wav), seed=7, **opts), ref)
    # the same samples as an array: int16, and float32 (x / 32768, as the WAV reader converts)
    assert_same(model.generate(pcm, sample_rate=16000, seed=7, **opts), ref)
    assert_same(model.generate(pcm.astype(np.float32) / 32768, sample_rate=16000, seed=7, **opts), ref)
    # the comparison can fail: another seed gives other motion
    other = model.generate(str(wav), seed=8, **opts)
    assert not np.array_equal(other["poses"], ref["poses"])


@pytest.mark.parametrize("family,backend", CASES)
def test_chunked_push_equals_cli(family, backend, models, cli, clips):
    bundle, extra = FAMILIES[family]
    model = models(family, backend)
    opts = cli_options(extra)
    for rate in (16000, 22050):
        wav, pcm = clips[rate]
        ref = cli.generate(wav, bundle, backend, 3, extra)
        stream = model.stream(seed=3, **opts)
        assert_same(chunked_push(stream, pcm, rate), ref)
        # reset: a cold start with the same seed gives the same frames
        stream.reset()
        assert stream.frames_emitted == 0 and stream.sample_rate is None
        assert_same(chunked_push(stream, pcm, rate), ref)
        # the whole input as one array at its own rate, through generate
        assert_same(model.generate(pcm, sample_rate=rate, seed=3, **opts), ref)


def test_streams_on_threads_equal_sequential(models, clips):
    model = models("livegesture", "tract")
    _, pcm = clips[16000]
    want = {s: chunked_push(model.stream(seed=s), pcm, 16000) for s in (1, 2, 3)}
    got = {}

    def run(seed):
        got[seed] = chunked_push(model.stream(seed=seed), pcm, 16000)

    threads = [threading.Thread(target=run, args=(s,)) for s in want]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    for s in want:
        for k in want[s]:
            assert np.array_equal(got[s][k], want[s][k])


def test_compute_releases_the_gil(models, speech):
    """Python code on another thread runs while generate computes (it would not if the GIL were
    held: the counting loop could not run at all until generate returned)."""
    model = models("livegesture", "tract")
    pcm = speech[: 16000 * 4]
    started = threading.Event()

    def work():
        started.set()
        model.generate(pcm, sample_rate=16000, seed=0)

    t = threading.Thread(target=work)
    t.start()
    started.wait()
    spins = 0
    while t.is_alive():
        spins += 1
    t.join()
    assert spins > 100_000, f"only {spins} iterations ran beside generate: the GIL was held"


def test_default_bundle_and_env(lgr, monkeypatch):
    monkeypatch.delenv("LIVEGESTURE_BUNDLE", raising=False)
    m = lgr.Model()
    assert pathlib.Path(m.path).resolve() == (ROOT / "models/default").resolve()
    assert m.family == "livegesture" and m.backend == "tract" and m.fps == 30
    monkeypatch.setenv("LIVEGESTURE_BUNDLE", str(ROOT / "models/diffsheg"))
    assert lgr.Model().family == "diffsheg"


def test_missing_and_non_wav_files_raise_the_cli_message(models, cli, tmp_path):
    model = models("livegesture", "tract")
    missing = tmp_path / "missing.wav"
    want = cli.error("generate", missing, "-o", tmp_path / "x.npz", "--bundle", FAMILIES["livegesture"][0])
    with pytest.raises(FileNotFoundError) as e:
        model.generate(str(missing))
    assert str(e.value) == want
    assert isinstance(e.value, OSError)
    text = tmp_path / "notes.wav"
    text.write_text("this is not audio\n")
    want = cli.error("generate", text, "-o", tmp_path / "x.npz", "--bundle", FAMILIES["livegesture"][0])
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
    want = chunked_push(model.stream(seed=3), x, 16000)
    for k in want:
        assert np.array_equal(got[k], want[k])


def test_wrong_bundles_raise(lgr, cli, tmp_path, clips):
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
    shutil.copytree(ROOT / "models/diffsheg", broken)
    with open(broken / "denoiser.onnx", "r+b") as f:
        f.seek(100)
        b = f.read(1)
        f.seek(100)
        f.write(bytes([b[0] ^ 0xFF]))
    want = cli.error("generate", wav, "-o", tmp_path / "x.npz", "--bundle", broken)
    with pytest.raises(ValueError) as e:
        lgr.Model(broken)
    assert str(e.value) == want and "sha256 mismatch" in want
    # a WAV file given as the bundle
    with pytest.raises(OSError):
        lgr.Model(wav)
    with pytest.raises(ValueError, match="unknown backend 'onnx'"):
        lgr.Model(ROOT / "models/default", backend="onnx")


def test_bad_options_and_arguments_raise(models, clips, tmp_path):
    lg, ds = models("livegesture", "tract"), models("diffsheg", "tract")
    wav, pcm = clips[16000]
    with pytest.raises(ValueError, match="guidance must be a finite number"):
        lg.stream(guidance=float("nan"))
    with pytest.raises(ValueError, match="temperature must be > 0"):
        lg.stream(temperature=0.0)
    with pytest.raises(ValueError, match="--ddim-steps"):
        lg.stream(ddim_steps=5)
    with pytest.raises(ValueError):
        ds.stream(ddim_steps=7)  # must divide the training steps
    with pytest.raises(ValueError, match="sample_rate is required"):
        lg.generate(pcm)
    with pytest.raises(ValueError, match="whose header gives the rate"):
        lg.generate(str(wav), sample_rate=16000)
    with pytest.raises(ValueError, match="no samples"):
        lg.generate(np.zeros(0, np.float32), sample_rate=16000)
    with pytest.raises(TypeError, match="1-D numpy array"):
        lg.stream().push([0.0, 0.1], 16000)
    with pytest.raises(ValueError, match="1-D"):
        lg.stream().push(np.zeros((100, 2), np.float32), 16000)
    with pytest.raises(ValueError, match="dtype int32 is not supported"):
        lg.stream().push(np.zeros(100, np.int32), 16000)
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


def test_an_empty_stream_finishes_with_no_frames(models):
    out = models("livegesture", "tract").stream().finish()
    assert out["poses"].shape == (0, 165) and out["index"].shape == (0,)


def test_stubs_match_the_module(lgr):
    """The installed .pyi names every public class, method and property of the module, and the wheel
    carries py.typed."""
    pkg = pathlib.Path(lgr.__file__).parent
    stub = next(p for p in [pkg / "livegesture_runtime.pyi", pkg / "__init__.pyi",
                            pathlib.Path(lgr.__file__).with_suffix(".pyi")] if p.exists())
    assert (pkg / "py.typed").exists()
    tree = ast.parse(stub.read_text())
    classes = {n.name: {f.name for f in n.body if isinstance(f, ast.FunctionDef)}
               for n in tree.body if isinstance(n, ast.ClassDef)}
    for cls in ("Model", "Stream"):
        public = {a for a in dir(getattr(lgr, cls)) if not a.startswith("_")}
        assert public == classes[cls] - {"__init__"}, cls
    assert os.path.basename(stub) in ("livegesture_runtime.pyi", "__init__.pyi")
