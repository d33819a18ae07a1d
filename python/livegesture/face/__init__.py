"""The face channel (docs/face.md): 15 viseme probabilities from a small causal viseme head on the streaming
log-mel features, and 52 ARKit blendshape weights made from them by a documented table (docs/face.md).

- :mod:`.names`   the ARKit-52 and viseme names in their fixed orders, the phone -> viseme map and the six
  mouth classes of the evaluation.
- :mod:`.labels`  pocketsphinx allphone decodes -> per-frame (30 fps) phone labels.
- :mod:`.head`    the viseme head (torch): offline causal forward and the cached step the ONNX graph runs.
- :mod:`.train`   trains it on the real-speech TRAIN split and synthetic speech.
- :mod:`.evaluate` lip-sync measurement on the real-speech VALIDATION split against an envelope baseline.
"""
