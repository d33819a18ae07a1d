"""The LiveGesture runtime: speech audio in, SMPL-X motion frames out (docs/python.md).

Each result is a dict of numpy arrays, one row per 30 fps frame:

- ``poses``: (n, 165) float32, SMPL-X axis-angle of 55 joints;
- ``trans``: (n, 3) float32, root translation in metres (Y up);
- ``expressions``: (n, 100) float32, face expression coefficients;
- ``index``: (n,) int64, frame indices from 0 (time = index / 30 s);
- ``arkit``: (n, 52) float32 in [0, 1], ARKit blendshape weights in ``ARKIT_NAMES`` order, and
  ``visemes``: (n, 15) float32 probabilities (each row sums to 1) in ``VISEME_NAMES`` order, from a
  bundle with the face channel (``Model.has_face``, docs/face.md); both None without one.

Errors carry the message of ``livegesture generate``: ``FileNotFoundError`` / ``OSError`` for files,
``ValueError`` for bad input (audio, bundle contents, options), ``RuntimeError`` otherwise. Every
computation releases the GIL.
"""

import os
from typing import TypedDict

import numpy as np
import numpy.typing as npt

__version__: str
FPS: int
POSE_DIM: int
TRANS_DIM: int
EXPR_DIM: int
ARKIT_DIM: int
VISEME_DIM: int
ARKIT_NAMES: list[str]
VISEME_NAMES: list[str]

class Frames(TypedDict):
    poses: npt.NDArray[np.float32]
    trans: npt.NDArray[np.float32]
    expressions: npt.NDArray[np.float32]
    index: npt.NDArray[np.int64]
    arkit: npt.NDArray[np.float32] | None
    visemes: npt.NDArray[np.float32] | None

Pcm = npt.NDArray[np.float32] | npt.NDArray[np.int16] | npt.NDArray[np.float64]

class Model:
    """A loaded model bundle on one backend; thread-safe, makes any number of streams.

    ``path=None`` takes the default bundle: ``$LIVEGESTURE_BUNDLE``, else the ``models/default`` of
    the checkout the module was built from (docs/python.md#the-default-bundle). ``backend`` is ``"tract"`` (pure Rust, CPU) or ``"ort"``
    (ONNX Runtime, from ``ORT_DYLIB_PATH``, ``ort_lib`` or an installed ``onnxruntime`` package;
    ``ep`` its execution provider, ``threads`` its intra-op threads). ``form`` picks a LiveGesture
    bundle's graph form (``auto``, ``canonical``, ``fused``, ``attention``).
    """

    def __init__(
        self,
        path: str | os.PathLike[str] | None = None,
        backend: str = "tract",
        *,
        ep: str = "cpu",
        threads: int = 1,
        ort_lib: str | os.PathLike[str] | None = None,
        form: str = "auto",
    ) -> None: ...
    @property
    def path(self) -> str:
        """The bundle folder."""
    @property
    def family(self) -> str:
        """``"livegesture"`` or ``"diffsheg"``."""
    @property
    def backend(self) -> str:
        """``"tract"`` or ``"ort"``."""
    @property
    def fps(self) -> int:
        """Output frames per second (30)."""
    @property
    def has_face(self) -> bool:
        """Whether results carry ``arkit`` and ``visemes`` (a bundle with the face channel)."""
    def stream(
        self,
        seed: int = 0,
        guidance: float | None = None,
        *,
        temperature: float | None = None,
        top_k: int | None = None,
        ddim_steps: int | None = None,
        jumps: int | None = None,
        window: int | None = None,
        overlap: int | None = None,
        blend_steps: int | None = None,
        speaker: int | None = None,
    ) -> Stream:
        """A new stream (cold start). None takes the bundle's default. ``temperature`` and ``top_k``
        are LiveGesture's; ``ddim_steps``, ``jumps``, ``window``, ``overlap``, ``blend_steps`` and
        ``speaker`` are DiffSHEG's (a family refuses the other's options with ValueError)."""
    def generate(
        self,
        audio: str | os.PathLike[str] | Pcm,
        sample_rate: int | None = None,
        seed: int = 0,
        guidance: float | None = None,
        *,
        temperature: float | None = None,
        top_k: int | None = None,
        ddim_steps: int | None = None,
        jumps: int | None = None,
        window: int | None = None,
        overlap: int | None = None,
        blend_steps: int | None = None,
        speaker: int | None = None,
    ) -> Frames:
        """Motion covering a whole input (ceil(seconds * 30) frames): a WAV file path, or a 1-D array
        of mono samples with its ``sample_rate``. Equals ``livegesture generate`` bit for bit for the
        same bundle, backend and options."""

class Stream:
    """One stream's state. Push audio in chunks of any size, then finish(); usable from any thread
    (calls on one stream are serialised)."""

    def push(self, pcm: Pcm, sample_rate: int = 16000) -> Frames:
        """Pushes 1-D mono samples (float32 in [-1, 1], int16 as x / 32768, float64 cast to float32)
        at ``sample_rate`` Hz; returns the frames they complete. The first push fixes the rate; other
        rates are resampled to 16 kHz by the stream's own resampler. NaN or infinite samples are
        refused (ValueError) without changing the stream."""
    def finish(self) -> Frames:
        """Ends the input: the remaining frames, so that all frames of the stream cover everything
        pushed (ceil(n * 30 / rate) frames)."""
    def reset(self) -> None:
        """Back to a cold start with the same options and seed (also after an error or finish())."""
    @property
    def frames_emitted(self) -> int:
        """Frames emitted so far."""
    @property
    def sample_rate(self) -> int | None:
        """The sample rate fixed by the first push (None before it)."""
    @property
    def guidance(self) -> float:
        """The classifier-free guidance scale in use."""
    @property
    def frames_per_unit(self) -> int:
        """Frames emitted together (4 for LiveGesture's tokens; a window step for DiffSHEG)."""
    @property
    def lookahead_frames(self) -> int:
        """How far past a unit, in frames, the audio must reach before it is emitted (0 for LiveGesture)."""
