"""The C# P/Invoke declarations of docs/c.md (examples/csharp/LiveGesture.cs), compiled with Debian's mono
(mcs): a whole WAV file and a chunked push loop give the poses of `livegesture generate` bit for bit, and
`lg_stream_read_face` its face channel (docs/face.md)."""
import os
import pathlib
import shutil
import subprocess

import numpy as np
import pytest

from conftest import FAMILIES, ROOT


@pytest.fixture(scope="module")
def exe(tmp_path_factory):
    mcs, mono = shutil.which("mcs"), shutil.which("mono")
    assert mcs and mono, "mcs/mono not found: apt-get install mono-mcs (scripts/test.sh does)"
    lib = ROOT / "target/release/liblivegesture_c.so"
    assert lib.is_file(), f"{lib}: build it first with scripts/build_c_example.sh"
    out = tmp_path_factory.mktemp("csharp") / "generate.exe"
    r = subprocess.run([mcs, "-nologo", f"-out:{out}", *sorted(map(str, (ROOT / "examples/csharp").glob("*.cs")))],
                       capture_output=True, text=True)
    assert r.returncode == 0, r.stdout + r.stderr
    return mono, out


def run(exe, *args):
    mono, out = exe
    env = dict(os.environ, LD_LIBRARY_PATH=str(ROOT / "target/release"))
    return subprocess.run([mono, str(out), *map(str, args)], capture_output=True, env=env, timeout=300)


def test_docs_show_the_declarations():
    """docs/c.md shows examples/csharp/LiveGesture.cs as it is (the file the other tests compile)."""
    cs = (ROOT / "examples/csharp/LiveGesture.cs").read_text()
    assert cs in (ROOT / "docs/c.md").read_text(), "docs/c.md: the C# block differs from examples/csharp/LiveGesture.cs"


def test_csharp_poses_equal_cli(exe, cli, clips):
    bundle = FAMILIES["livegesture"][0]
    for rate in (16000, 22050):
        wav, _ = clips[rate]
        ref = cli.generate(wav, bundle, "tract", 11)["poses"]
        for mode in ([], ["push"]):
            r = run(exe, bundle, wav, 11, *mode)
            assert r.returncode == 0, r.stderr.decode()
            got = np.frombuffer(r.stdout, dtype="<f4")
            assert got.size == ref.size and np.array_equal(got.reshape(-1, 165), ref), (rate, mode)


def test_csharp_face_channel_equals_cli(exe, cli, clips):
    """models/default's face channel through lg_stream_read_face: the ARKit weights and visemes of the CLI's
    npz bit for bit, and the names of docs/face.md; a bundle without the face channel is refused."""
    bundle = FAMILIES["livegesture"][0]
    wav, _ = clips[16000]
    ref = cli.generate(wav, bundle, "tract", 5)
    assert ref["arkit"] is not None, f"{bundle}: the reference has no face channel"
    r = run(exe, bundle, wav, 5, "face")
    assert r.returncode == 0, r.stderr.decode()
    names = r.stderr.decode().split("\n")
    arkit = [n.split(" ", 1)[1] for n in names if n.startswith("arkit ")]
    visemes = [n.split(" ", 1)[1] for n in names if n.startswith("viseme ")]
    assert len(arkit) == 52 and arkit[0] == "eyeBlinkLeft" and "jawOpen" in arkit and arkit[-1] == "tongueOut"
    assert visemes == "sil PP FF TH DD kk CH SS nn RR aa E ih oh ou".split()
    got = np.frombuffer(r.stdout, dtype="<f4").reshape(-1, 67)
    assert np.array_equal(got[:, :52], ref["arkit"]), np.abs(got[:, :52] - ref["arkit"]).max()
    assert np.array_equal(got[:, 52:], ref["visemes"]), np.abs(got[:, 52:] - ref["visemes"]).max()
    tiny = pathlib.Path(os.environ.get("LIVEGESTURE_TEST_BUNDLE", ROOT / "target/test-bundles/tiny"))
    r = run(exe, tiny, wav, 5, "face")
    assert r.returncode == 2 and r.stdout == b"" and b"has no face channel" in r.stderr, r.stderr


def test_csharp_gets_the_error_message(exe, tmp_path):
    r = run(exe, FAMILIES["livegesture"][0], tmp_path / "missing.wav", 1)
    assert r.returncode == 2 and r.stdout == b""
    assert b"missing.wav: no such file; expected a WAV file" in r.stderr, r.stderr
