"""Fixtures of the checks of the Python module and the C example against the CLI (scripts/test.sh runs
them after building target/release/livegesture, the wheel and target/c/generate): the CLI as the
reference, short clips of the shipped reference speech."""
import os
import pathlib
import subprocess
import wave

import numpy as np
import pytest

ROOT = pathlib.Path(__file__).resolve().parents[2]

# the shipped bundles of both families; DiffSHEG with 5 DDIM steps to keep the runs short
FAMILIES = {
    "livegesture": (ROOT / "models/default", []),
    "diffsheg": (ROOT / "models/diffsheg", ["--ddim-steps", "5"]),
}
BACKENDS = ["tract", "ort"]
# the Python module's checks run the fresh tiny exports of both families (scripts/test.sh makes them and
# exports these variables; fast), and models/default once
TINY = {
    "livegesture": (pathlib.Path(os.environ.get("LIVEGESTURE_TEST_BUNDLE", ROOT / "target/test-bundles/tiny")), []),
    "diffsheg": (pathlib.Path(os.environ.get("LIVEGESTURE_DIFFSHEG_TINY_BUNDLE",
                                             ROOT / "target/test-bundles/diffsheg-tiny")), ["--ddim-steps", "5"]),
}


def cli_options(extra):
    """CLI flags -> the module's keyword arguments (--ddim-steps 5 -> ddim_steps=5)."""
    return {extra[i].lstrip("-").replace("-", "_"): int(extra[i + 1]) for i in range(0, len(extra), 2)}


@pytest.fixture(scope="session")
def binary():
    b = pathlib.Path(os.environ.get("LIVEGESTURE_BIN", ROOT / "target/release/livegesture"))
    assert b.is_file(), f"{b}: build it first (cargo build --release -p livegesture) or set LIVEGESTURE_BIN"
    return b


def write_wav(path, pcm_int16, rate):
    with wave.open(str(path), "wb") as w:
        w.setnchannels(1)
        w.setsampwidth(2)
        w.setframerate(rate)
        w.writeframes(np.asarray(pcm_int16, dtype="<i2").tobytes())
    return path


@pytest.fixture(scope="session")
def speech():
    """The reference speech clip of models/default (16 kHz mono int16)."""
    with wave.open(str(ROOT / "models/default/reference/clip.wav"), "rb") as w:
        assert w.getsampwidth() == 2 and w.getnchannels() == 1 and w.getframerate() == 16000
        return np.frombuffer(w.readframes(w.getnframes()), dtype="<i2").copy()


@pytest.fixture(scope="session")
def clips(tmp_path_factory, speech):
    """Two WAV files: 1.3 s at 16 kHz (not a whole number of tokens), and 1.1 s of other samples
    declared as 22050 Hz (resampled by the reader and by a stream's own resampler)."""
    d = tmp_path_factory.mktemp("clips")
    a = speech[: int(1.3 * 16000)]
    b = speech[8000 : 8000 + int(1.1 * 22050)]
    return {
        16000: (write_wav(d / "speech16k.wav", a, 16000), a),
        22050: (write_wav(d / "speech22k.wav", b, 22050), b),
    }


class Cli:
    """`livegesture generate` as the reference, results cached per (wav, bundle, backend, seed, flags)."""

    def __init__(self, binary, tmp):
        self.binary, self.tmp, self.cache = binary, tmp, {}

    def run(self, *args):
        return subprocess.run([str(self.binary), *map(str, args)], capture_output=True, text=True)

    def generate(self, wav, bundle, backend, seed, extra=()):
        key = (str(wav), str(bundle), backend, seed, tuple(extra))
        if key not in self.cache:
            out = self.tmp / f"ref{len(self.cache)}.npz"
            r = self.run("generate", wav, "-o", out, "--bundle", bundle, "--backend", backend,
                         "--seed", seed, *extra)
            assert r.returncode == 0, r.stderr
            with np.load(out) as z:
                self.cache[key] = {k: z[k] for k in ("poses", "trans", "expressions")}
                # the face channel: in the npz from a bundle with a face graph, else absent (None here)
                for k in ("arkit", "visemes"):
                    self.cache[key][k] = z[k] if k in z.files else None
        return self.cache[key]

    def error(self, *args):
        """The CLI's error message (after `livegesture: error: `) for a failing command."""
        r = self.run(*args)
        assert r.returncode != 0, r.stderr
        line = [ln for ln in r.stderr.splitlines() if ln.startswith("livegesture: error: ")][-1]
        return line[len("livegesture: error: "):]


@pytest.fixture(scope="session")
def cli(binary, tmp_path_factory):
    return Cli(binary, tmp_path_factory.mktemp("cli"))


@pytest.fixture(scope="session")
def lgr():
    import livegesture_runtime

    return livegesture_runtime


@pytest.fixture(scope="session")
def models(lgr):
    """Models of the tiny bundles (TINY), loaded once per (family, backend)."""
    cache = {}

    def get(family, backend):
        if (family, backend) not in cache:
            if backend == "ort":
                assert os.environ.get("ORT_DYLIB_PATH"), "ORT_DYLIB_PATH: source scripts/env.sh first"
            bundle = TINY[family][0]
            assert (bundle / "manifest.json").is_file(), f"{bundle}: export it first (scripts/test.sh does)"
            cache[family, backend] = lgr.Model(bundle, backend=backend)
        return cache[family, backend]

    return get


def assert_same(got, ref):
    """Frames equal the CLI's bit for bit, with indices 0..n-1."""
    n = len(ref["poses"])
    assert set(got) == {"poses", "trans", "expressions", "index", "arkit", "visemes"}
    assert got["poses"].dtype == np.float32 and got["poses"].shape == (n, 165)
    assert got["trans"].dtype == np.float32 and got["trans"].shape == (n, 3)
    assert got["expressions"].dtype == np.float32 and got["expressions"].shape == (n, 100)
    assert got["index"].dtype == np.int64 and np.array_equal(got["index"], np.arange(n))
    for k in ("poses", "trans", "expressions"):
        assert np.array_equal(got[k], ref[k]), f"{k}: max abs diff {np.abs(got[k] - ref[k]).max()}"
    assert_same_face(got, ref, n)


def assert_same_face(got, ref, n):
    """The face channel (docs/face.md) as the reference has it: None for a bundle without a face graph;
    else arkit (n, 52) in [0, 1] and visemes (n, 15) summing to 1, bit for bit the reference's."""
    if ref.get("arkit") is None:
        assert got["arkit"] is None and got["visemes"] is None, "a bundle without a face gave face values"
        return
    assert got["arkit"] is not None and got["visemes"] is not None, "the face channel is missing"
    assert got["arkit"].dtype == np.float32 and got["arkit"].shape == (n, 52)
    assert got["visemes"].dtype == np.float32 and got["visemes"].shape == (n, 15)
    assert np.isfinite(got["arkit"]).all() and (got["arkit"] >= 0).all() and (got["arkit"] <= 1).all()
    assert np.isfinite(got["visemes"]).all() and np.allclose(got["visemes"].sum(1), 1, atol=1e-5)
    for k in ("arkit", "visemes"):
        assert np.array_equal(got[k], ref[k]), f"{k}: max abs diff {np.abs(got[k] - ref[k]).max()}"


def concat(parts):
    out = {k: np.concatenate([p[k] for p in parts]) for k in ("poses", "trans", "expressions", "index")}
    for k in ("arkit", "visemes"):  # None in every part without the face channel
        out[k] = None if parts[0][k] is None else np.concatenate([p[k] for p in parts])
    return out
