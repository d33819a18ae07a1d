"""A CUDA device emulated on CPU-only machines, for tests: ``with VirtualCuda() as vc: train(..., device="cuda")``.

Everything runs on the CPU, but every tensor remembers where it would live on a machine with a GPU: on the
"cuda" device (moved there with ``.to("cuda")``/``.cuda()``, created with ``device="cuda"`` or computed from
such a tensor) or on the host (created without a device, ``torch.from_numpy``, ``.cpu()``). Then, as on a
real GPU:

- an operation mixing a cuda tensor and a host tensor (other than a 0-dim one, which CUDA accepts as a
  scalar) raises ``RuntimeError("Expected all tensors to be on the same device ...")``; the cross-device
  operations CUDA allows (``copy_``, ``.to``, indexing with host indices) are allowed;
- ``.numpy()`` / ``np.asarray`` of a cuda tensor raises; ``tensor.device`` is ``cuda:0`` and ``is_cuda``
  True, so code that follows ``x.device`` creates its tensors "on the GPU";
- host synchronisations (``.item()``, ``float()``, ``.tolist()``, ``bool()``, ``.cpu()``, ``nonzero``,
  boolean-mask indexing of cuda tensors) are counted in ``syncs`` (function names), so a test can check
  that a training loop does not wait for the GPU at every step.

Where a tensor lives is recorded per storage (views and in-place results share it). Storages are kept
alive while the mode is active so that their addresses are not reused. Tensors made outside the mode (or by
the autograd engine: gradients) are of unknown place and never raise. Thread-local: tensors made on other
threads (data workers) inside the block are host tensors when they enter this thread's operations
without a device tag, which is what they are on a GPU machine too.
"""
from __future__ import annotations

import os
import sys

import torch
from torch.overrides import TorchFunctionMode
from torch.utils._pytree import tree_flatten

CUDA, HOST = "cuda", "cpu"
_SYNC = {"item", "__float__", "__int__", "__bool__", "__index__", "tolist", "nonzero", "argwhere",
         "masked_select", "unique", "equal", "allclose"}
# operations CUDA performs across devices
_CROSS_OK = {"copy_", "__getitem__", "__setitem__", "index_put_", "index_put", "_has_compatible_shallow_copy_type",
             "__set__", "set_", "__get__", "is_pinned", "_parse_to"}


def _torch_internal() -> bool:
    """Whether the operation was called by torch's own Python code (not by the code under test)."""
    f = sys._getframe(1)
    while f is not None and f.f_code.co_filename == __file__:
        f = f.f_back
    while f is not None and f.f_code.co_filename.endswith(("overrides.py", "_device.py")):
        f = f.f_back
    return f is not None and _TORCH_DIR in f.f_code.co_filename


_TORCH_DIR = os.path.dirname(torch.__file__)


def _name(func) -> str:
    return getattr(func, "__name__", str(func))


class VirtualCuda(TorchFunctionMode):
    def __init__(self):
        super().__init__()
        self.where: dict[int, str] = {}
        self._keep = []
        self.syncs: list[str] = []
        self.ops = 0

    # ------------------------------------------------------------------ bookkeeping
    @staticmethod
    def _ptr(t) -> int:
        try:
            return t.untyped_storage().data_ptr()
        except Exception:   # noqa: BLE001 - sparse, meta, ...: no place
            return 0

    def place(self, t) -> str | None:
        p = self._ptr(t)
        return self.where.get(p) if p else None

    def _mark(self, out, kind: str | None, force: bool = False):
        if kind is None:
            return
        for t in tree_flatten(out)[0]:
            if isinstance(t, torch.Tensor):
                p = self._ptr(t)
                if p and (force or p not in self.where):
                    self.where[p] = kind
                    self._keep.append(t.untyped_storage())

    def _to(self, t, device, dtype, non_blocking, copy=False):
        src = self.place(t)
        dtype = dtype or t.dtype
        if device.type == CUDA:
            if src == CUDA:
                return t.to(dtype=dtype, copy=copy)
            out = t.to(dtype=dtype, copy=True)
            self._mark(out, CUDA, force=True)
            return out
        if device.type == HOST and src == CUDA:
            if _torch_internal():
                # torch's own code grouping tensors by their real device (gradient clipping, optimisers)
                # asks for the CPU here; on a GPU it asks for the GPU: the same tensor
                return t.to(dtype=dtype, copy=copy)
            if not non_blocking:
                self.syncs.append("to(cpu)")
            out = t.to(dtype=dtype, copy=True)
            self._mark(out, HOST, force=True)
            return out
        out = t.to(device=device, dtype=dtype, non_blocking=non_blocking, copy=copy)
        self._mark(out, src or HOST)
        return out

    # ------------------------------------------------------------------ the mode
    def __torch_function__(self, func, types, args=(), kwargs=None):
        kwargs = dict(kwargs or {})
        self.ops += 1
        name = _name(func)
        if name == "__get__":                                  # tensor properties
            prop = getattr(getattr(func, "__self__", None), "__name__", "")
            t = args[0] if args else None
            if isinstance(t, torch.Tensor) and self.place(t) == CUDA:
                if prop == "device":
                    return torch.device("cuda", 0)
                if prop == "is_cuda":
                    return True
                if prop == "is_cpu":
                    return False
                if prop == "grad":                             # gradients live with their parameter
                    out = func(*args, **kwargs)
                    self._mark(out, CUDA, force=True)
                    return out
            return func(*args, **kwargs)
        if name == "get_device" and args and self.place(args[0]) == CUDA:
            return 0
        if name in ("to", "cuda", "cpu") and args and isinstance(args[0], torch.Tensor):
            t = args[0]
            if name == "cuda":
                return self._to(t, torch.device(CUDA), None, kwargs.get("non_blocking", False))
            if name == "cpu":
                return self._to(t, torch.device(HOST), None, False) if self.place(t) == CUDA else t
            copy = kwargs.pop("copy", False)
            rest = list(args[1:])
            if rest and isinstance(rest[0], torch.Tensor):     # .to(other): its device and dtype
                other = rest.pop(0)
                dev = torch.device(CUDA) if self.place(other) == CUDA else other.device
                return self._to(t, dev, other.dtype, kwargs.get("non_blocking", False), copy)
            device, dtype, non_blocking, _ = torch._C._nn._parse_to(*rest, **kwargs)
            if device is None:
                out = func(*args, **kwargs, **({"copy": copy} if copy else {}))
                self._mark(out, self.place(t))
                return out
            return self._to(t, device, dtype, non_blocking, copy)
        if name in ("numpy", "__array__") and args and self.place(args[0]) == CUDA:
            raise TypeError("can't convert cuda:0 device type tensor to numpy. Use Tensor.cpu() to copy the "
                            "tensor to host memory first. (devicecheck.VirtualCuda)")
        if name == "pin_memory":
            out = args[0].clone()
            self._mark(out, HOST, force=True)
            return out
        if name == "is_pinned":
            return False
        # factories: device="cuda" runs on the CPU and marks the result
        target = None
        if "device" in kwargs and kwargs["device"] is not None:
            dev = torch.device(kwargs["device"]) if not isinstance(kwargs["device"], torch.device) else kwargs["device"]
            if dev.type == CUDA:
                kwargs["device"] = HOST
                target = CUDA
            else:
                target = HOST
        kwargs.pop("pin_memory", None)
        tensors = [t for t in tree_flatten((args, kwargs))[0] if isinstance(t, torch.Tensor)]
        places = [self.place(t) for t in tensors]
        on_cuda = CUDA in places
        if on_cuda and name not in _CROSS_OK:
            host = [t for t, p in zip(tensors, places) if p == HOST and t.dim() > 0]
            if host:
                raise RuntimeError(
                    f"Expected all tensors to be on the same device, but found at least two devices, cuda:0 and "
                    f"cpu! (devicecheck.VirtualCuda: {name} got a host tensor of shape {tuple(host[0].shape)})")
        if on_cuda and (name in _SYNC or (name in ("__getitem__", "__setitem__", "index_put_")
                                           and any(t.dtype == torch.bool for t in tensors[1:]))):
            self.syncs.append(name)
        out = func(*args, **kwargs)
        if target is None:
            if on_cuda:
                target = CUDA
            elif not tensors or any(p == HOST and t.dim() > 0 for t, p in zip(tensors, places)):
                target = HOST   # (a 0-dim host tensor is a scalar: it does not make a result a host tensor)
        self._mark(out, target)
        return out

    def count_syncs(self) -> int:
        return len(self.syncs)
