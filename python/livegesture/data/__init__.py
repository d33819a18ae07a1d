"""Data: BEAT2 motion features (:mod:`.features`), the BEAT2 loader (:mod:`.beat2`) and the synthetic
corpus generator that writes the BEAT2 layout (:mod:`.synth`, ``python -m livegesture.data.synth``; its speech
in :mod:`.synth_speech`, its audio analysis and motion in :mod:`.synth_motion`)."""
from .features import NormStats, features_to_motion, foot_contact, motion_to_features

__all__ = ["NormStats", "features_to_motion", "foot_contact", "motion_to_features"]
