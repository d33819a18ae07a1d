import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
# the repository root: the exporter is the package `export` there (export/__init__.py)
sys.path.insert(0, str(Path(__file__).resolve().parents[2]))

import torch  # noqa: E402

# One intra-op thread: the machines are shared, and OpenMP spin-waiting under contention makes
# multi-threaded small ops orders of magnitude slower.
torch.set_num_threads(1)

import pytest  # noqa: E402


@pytest.fixture(scope="session")
def tiny_corpus(tmp_path_factory):
    """A small synthetic corpus in the BEAT2 layout (espeak-ng speech), shared by the tests of a session."""
    from livegesture.data.synth import generate_corpus
    out = tmp_path_factory.mktemp("corpus")
    generate_corpus(out, minutes=0.6, seed=3, jobs=1, clip_seconds=(10.0, 14.0), progress=False)
    return out
