"""LiveGesture components, one file each. Every component has two entry points over the same weights:

- ``forward(...)``: the offline causal forward over a whole sequence (training);
- ``step(..., cache)``: one token step with an explicit cache (a dict of plain tensors, batch on axis 0),
  returning ``(outputs, new_cache)``. Step functions contain no data-dependent Python control flow, use
  fixed-size caches and the same bounded windows as the training masks; they are what ``export/`` turns
  into ONNX graphs.
"""
from .audio_encoder import AudioEncoder
from .expert import RegionExpert
from .fuse import XARFuse
from .model import LiveGesture
from .svq import SVQ

__all__ = ["AudioEncoder", "SVQ", "RegionExpert", "XARFuse", "LiveGesture"]
