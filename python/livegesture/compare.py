"""The one comparison of two tensors used by the export checks and the Python tests (docs/parity.md).

A bound is on the largest absolute difference over one tensor, scaled by the reference tensor's magnitude:
``max|got - ref| <= bound * max(1, max|ref|)``. Below magnitude 1 the bound is absolute; above it, relative.
The same semantics as the Rust runtime's ``livegesture::compare``.

A comparison fails, whatever the bound, when a value on either side is NaN or infinite (``Diff.nonfinite``
says which side and where: ``np.abs(a - b).max()`` with a NaN is NaN, and ``nan <= bound`` is False, but
``max(..., key=...)`` or ``np.nanmax`` style code silently skips it), when nothing was compared (two empty
tensors prove nothing), and when the shapes differ (no broadcasting).

    >>> diff(np.float32([40.0 + 4 * 3.8e-6]), np.float32([40.0])).within(1e-5)
    True
    >>> diff(np.float32([np.nan]), np.float32([40.0])).within(1e-5)
    False
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Optional, Tuple

import numpy as np

__all__ = ["Diff", "diff", "assert_within"]


@dataclass
class Diff:
    """The result of comparing ``got`` with ``ref`` (see :func:`diff`)."""

    #: the largest ``|got - ref|`` over the compared values; ``inf`` when the comparison cannot pass
    #: (non-finite value, nothing compared, shapes that differ), so code that reads only this field still fails.
    max_abs: float
    #: the flat index of the largest difference, or of the first non-finite value
    index: Optional[int]
    #: ``max(1, max|ref|)`` over the finite reference values
    scale: float
    #: how many value pairs were compared
    compared: int
    #: a NaN or infinite value on either side: which side(s) and where, e.g. ``got[0, 17] = nan``
    nonfinite: Optional[str] = None
    #: ``(got.shape, ref.shape)`` when they differ
    shape_mismatch: Optional[Tuple[tuple, tuple]] = None
    #: ``(got, ref)`` at ``index``
    values: Optional[Tuple[float, float]] = None
    #: the multi-dimensional index of ``index`` in the compared shape
    where: Optional[tuple] = None

    def within(self, bound: float) -> bool:
        """Every value finite on both sides, something compared, equal shapes, ``max_abs <= bound * scale``."""
        return (
            self.nonfinite is None
            and self.shape_mismatch is None
            and self.compared > 0
            and self.max_abs <= bound * self.scale
        )

    @property
    def scaled_error(self) -> float:
        """``max_abs / scale``: what is compared with the bound."""
        return self.max_abs / self.scale

    def problem(self) -> Optional[str]:
        """Why this comparison cannot pass any bound, if it cannot."""
        if self.shape_mismatch is not None:
            g, r = self.shape_mismatch
            return f"shapes differ: got {g}, reference {r}"
        if self.nonfinite is not None:
            return f"non-finite value: {self.nonfinite}"
        if self.compared == 0:
            return "nothing compared (both sides empty)"
        return None

    def worst(self, other: "Diff") -> "Diff":
        """The worse of two comparisons: one no bound passes first, then the larger scaled error."""
        if self.problem() is not None:
            return self
        if other.problem() is not None:
            return other
        return other if other.scaled_error > self.scaled_error else self

    def describe(self) -> str:
        """One line for a failure message: the error, the scale, where, and the value pair."""
        p = self.problem()
        if p is not None:
            return f"{p} ({self.compared} compared)"
        s = (
            f"max |got - reference| = {self.max_abs:.3e} (scaled {self.scaled_error:.3e}, "
            f"scale {self.scale:.4f}, {self.compared} compared)"
        )
        if self.values is not None:
            s += f" at {list(self.where) if self.where is not None else self.index}: got {self.values[0]!r}, reference {self.values[1]!r}"
        return s

    __str__ = describe

    def ensure(self, bound: float, what: str = "") -> "Diff":
        """Returns self when within ``bound``, else raises AssertionError naming ``what``, the error and the scale."""
        if not self.within(bound):
            raise AssertionError(
                f"{what + ': ' if what else ''}{self.describe()}; bound {bound:g} x scale {self.scale:.4f} = "
                f"{bound * self.scale:.3e}"
            )
        return self


def _as_array(x) -> np.ndarray:
    if hasattr(x, "detach"):  # a torch tensor, without importing torch
        x = x.detach().cpu().numpy()
    return np.asarray(x)


def _nonfinite_index(a: np.ndarray) -> Optional[int]:
    bad = ~np.isfinite(a)
    return int(np.argmax(bad)) if bad.any() else None


def diff(got, ref) -> Diff:
    """Compares ``got`` with ``ref`` (numpy arrays, torch tensors or sequences) element by element."""
    g = _as_array(got)
    r = _as_array(ref)
    if g.shape != r.shape:
        n = min(g.size, r.size)
        return Diff(max_abs=float("inf"), index=None, scale=1.0, compared=n, shape_mismatch=(g.shape, r.shape))
    shape = g.shape
    g = g.astype(np.float64, copy=False).reshape(-1)
    r = r.astype(np.float64, copy=False).reshape(-1)
    n = int(g.size)
    if n == 0:
        return Diff(max_abs=float("inf"), index=None, scale=1.0, compared=0)
    finite_r = np.isfinite(r)
    scale = float(max(1.0, np.abs(r[finite_r]).max() if finite_r.any() else 1.0))
    ig, ir = _nonfinite_index(g), _nonfinite_index(r)
    if ig is not None or ir is not None:
        i = min(x for x in (ig, ir) if x is not None)
        where = np.unravel_index(i, shape) if shape else ()
        at = "[" + ", ".join(str(int(k)) for k in where) + "]"
        gi, ri = g[i], r[i]
        if not np.isfinite(gi) and not np.isfinite(ri):
            text = f"both sides at {at}: got {gi}, reference {ri}"
        elif not np.isfinite(gi):
            text = f"got{at} = {gi} (reference {ri})"
        else:
            text = f"reference{at} = {ri} (got {gi})"
        return Diff(
            max_abs=float("inf"),
            index=i,
            scale=scale,
            compared=n,
            nonfinite=text,
            values=(float(gi), float(ri)),
            where=tuple(int(k) for k in where),
        )
    d = np.abs(g - r)
    i = int(np.argmax(d))
    where = tuple(int(k) for k in np.unravel_index(i, shape)) if shape else ()
    return Diff(
        max_abs=float(d[i]), index=i, scale=scale, compared=n, values=(float(g[i]), float(r[i])), where=where
    )


def assert_within(got, ref, bound: float, what: str = "") -> Diff:
    """Raises AssertionError (naming ``what``, the error, the scale, where) unless ``got`` is within ``bound``
    (scaled) of ``ref``; returns the :class:`Diff` otherwise. For tests and export checks."""
    return diff(got, ref).ensure(bound, what)
