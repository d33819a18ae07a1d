"""Shared fixtures of the Python checks of the Rust binary (run by scripts/test.sh after the build)."""
import os
import pathlib
import re
import subprocess
import wave

import numpy as np
import pytest

ROOT = pathlib.Path(__file__).resolve().parents[3]


@pytest.fixture(scope="session")
def binary():
    b = pathlib.Path(os.environ.get("LIVEGESTURE_BIN", ROOT / "target/release/livegesture"))
    assert b.is_file(), f"{b}: build it first (cargo build --release -p livegesture) or set LIVEGESTURE_BIN"
    return b


@pytest.fixture(scope="session")
def bundle():
    return ROOT / "models/default"


def write_wav(path, pcm_int16: np.ndarray, rate: int, channels: int = 1):
    with wave.open(str(path), "wb") as w:
        w.setnchannels(channels)
        w.setsampwidth(2)
        w.setframerate(rate)
        w.writeframes(pcm_int16.astype("<i2").tobytes())


@pytest.fixture(scope="session")
def speech_wav(tmp_path_factory, bundle):
    """2.9 s of the bundle's reference speech clip (16 kHz mono s16le): not a whole number of tokens."""
    with wave.open(str(bundle / "reference/clip.wav"), "rb") as w:
        rate = w.getframerate()
        assert w.getsampwidth() == 2 and w.getnchannels() == 1
        pcm = np.frombuffer(w.readframes(w.getnframes()), dtype="<i2")
    n = int(2.9 * rate)
    path = tmp_path_factory.mktemp("audio") / "speech.wav"
    write_wav(path, pcm[:n], rate)
    return path, n, rate


class Server:
    def __init__(self, binary, bundle, *extra):
        self.proc = subprocess.Popen(
            [str(binary), "serve", "--addr", "127.0.0.1:0", "--backend", "tract", "--bundle", str(bundle), *extra],
            stderr=subprocess.PIPE, text=True)
        for line in self.proc.stderr:
            m = re.search(r"listening on http://(\S+)", line)
            if m:
                self.addr = m.group(1)
                break
        else:
            raise RuntimeError(f"serve did not start (exit {self.proc.wait()})")
        self.url = f"ws://{self.addr}"

    def stop(self):
        self.proc.terminate()
        rest = self.proc.stderr.read()
        code = self.proc.wait(timeout=30)
        return code, rest


@pytest.fixture
def server(binary, bundle):
    s = Server(binary, bundle, "--max-message-bytes", "65536", "--idle-timeout", "5")
    yield s
    code, log = s.stop()
    assert code == 0, log
