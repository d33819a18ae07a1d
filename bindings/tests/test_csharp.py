"""The C# P/Invoke declarations of docs/c.md (examples/csharp/LiveGesture.cs), compiled with Debian's mono
(mcs): a whole WAV file and a chunked push loop give the poses of `livegesture generate` bit for bit."""
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


def test_csharp_gets_the_error_message(exe, tmp_path):
    r = run(exe, FAMILIES["livegesture"][0], tmp_path / "missing.wav", 1)
    assert r.returncode == 2 and r.stdout == b""
    assert b"missing.wav: no such file; expected a WAV file" in r.stderr, r.stderr
