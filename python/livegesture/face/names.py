"""Names, orders and tables of the face channel (docs/face.md)."""
from __future__ import annotations

import numpy as np

# Apple's 52 ARKit blendshapes in Apple's documented order (ARFaceAnchor.BlendShapeLocation, grouped as
# Apple lists them: left eye, right eye, mouth and jaw, eyebrows, cheeks, nose, tongue).
ARKIT_NAMES: tuple[str, ...] = (
    "eyeBlinkLeft", "eyeLookDownLeft", "eyeLookInLeft", "eyeLookOutLeft", "eyeLookUpLeft", "eyeSquintLeft",
    "eyeWideLeft",
    "eyeBlinkRight", "eyeLookDownRight", "eyeLookInRight", "eyeLookOutRight", "eyeLookUpRight",
    "eyeSquintRight", "eyeWideRight",
    "jawForward", "jawLeft", "jawRight", "jawOpen",
    "mouthClose", "mouthFunnel", "mouthPucker", "mouthLeft", "mouthRight", "mouthSmileLeft", "mouthSmileRight",
    "mouthFrownLeft", "mouthFrownRight", "mouthDimpleLeft", "mouthDimpleRight", "mouthStretchLeft",
    "mouthStretchRight", "mouthRollLower", "mouthRollUpper", "mouthShrugLower", "mouthShrugUpper",
    "mouthPressLeft", "mouthPressRight", "mouthLowerDownLeft", "mouthLowerDownRight", "mouthUpperUpLeft",
    "mouthUpperUpRight",
    "browDownLeft", "browDownRight", "browInnerUp", "browOuterUpLeft", "browOuterUpRight",
    "cheekPuff", "cheekSquintLeft", "cheekSquintRight",
    "noseSneerLeft", "noseSneerRight",
    "tongueOut",
)
assert len(ARKIT_NAMES) == 52 and len(set(ARKIT_NAMES)) == 52

# The OpenXR / Oculus Lipsync visemes in their order.
VISEME_NAMES: tuple[str, ...] = ("sil", "PP", "FF", "TH", "DD", "kk", "CH", "SS", "nn", "RR", "aa", "E", "ih",
                                 "oh", "ou")
assert len(VISEME_NAMES) == 15

# pocketsphinx en-us phones (CMUdict ARPAbet, stress removed) -> viseme. The vowels follow the evaluation's
# mouth classes (open: AA AE AH AO AW AY -> aa; round: OW OY UH UW W -> oh/ou; spread: IY IH EY EH Y -> E/ih);
# the consonants follow Oculus' viseme reference (PP: p b m; FF: f v; TH; DD: t d; kk: k g; CH: ch jh sh zh;
# SS: s z; nn: n l; RR: r). HH and NG have no viseme of their own: HH -> kk (open throat, lips neutral),
# NG -> kk (velar, like k g). ER -> RR. Fillers (+NSN+ +SPN+ ...) and SIL -> sil.
PHONE_TO_VISEME: dict[str, str] = {
    "SIL": "sil",
    "P": "PP", "B": "PP", "M": "PP",
    "F": "FF", "V": "FF",
    "TH": "TH", "DH": "TH",
    "T": "DD", "D": "DD",
    "K": "kk", "G": "kk", "NG": "kk", "HH": "kk",
    "CH": "CH", "JH": "CH", "SH": "CH", "ZH": "CH",
    "S": "SS", "Z": "SS",
    "N": "nn", "L": "nn",
    "R": "RR", "ER": "RR",
    "AA": "aa", "AE": "aa", "AH": "aa", "AO": "aa", "AW": "aa", "AY": "aa",
    "EH": "E", "EY": "E",
    "IH": "ih", "IY": "ih", "Y": "ih",
    "OW": "oh", "OY": "oh",
    "UH": "ou", "UW": "ou", "W": "ou",
}


def phone_viseme(phone: str) -> int:
    """A pocketsphinx phone (or filler such as ``+SPN+``) -> viseme index; unknown symbols raise."""
    p = phone.upper()
    if p.startswith("+") or p.startswith("<") or p == "SIL":
        return 0
    if p not in PHONE_TO_VISEME:
        raise ValueError(f"face: unknown phone {phone!r} (expected a pocketsphinx en-us phone or filler)")
    return VISEME_NAMES.index(PHONE_TO_VISEME[p])


# The six mouth classes of the lip-sync measurement (issue 41).
MOUTH_CLASSES: tuple[str, ...] = ("silence", "bilabial", "open", "round", "spread", "other")
_PHONE_MOUTH = {**{p: 1 for p in ("M", "B", "P")},
                **{p: 2 for p in ("AA", "AE", "AH", "AO", "AW", "AY")},
                **{p: 3 for p in ("OW", "UW", "UH", "OY", "W")},
                **{p: 4 for p in ("IY", "IH", "EY", "EH", "Y")}}
_VISEME_MOUTH = {"sil": 0, "PP": 1, "aa": 2, "oh": 3, "ou": 3, "E": 4, "ih": 4}


def phone_mouth(phone: str) -> int:
    p = phone.upper()
    if p.startswith("+") or p.startswith("<") or p == "SIL":
        return 0
    return _PHONE_MOUTH.get(p, 5)


VISEME_MOUTH = np.array([_VISEME_MOUTH.get(v, 5) for v in VISEME_NAMES], dtype=np.int64)

# viseme -> ARKit mouth/jaw weights (each viseme's pose; a frame's weights are the probability-weighted
# sum). Values hand-set from the Oculus viseme reference images and Apple's shape descriptions.
VISEME_ARKIT: dict[str, dict[str, float]] = {
    "sil": {"mouthClose": 0.05},
    "PP": {"mouthClose": 0.6, "mouthPressLeft": 0.5, "mouthPressRight": 0.5, "mouthRollLower": 0.2,
           "mouthRollUpper": 0.2},
    "FF": {"jawOpen": 0.08, "mouthRollLower": 0.55, "mouthUpperUpLeft": 0.25, "mouthUpperUpRight": 0.25},
    "TH": {"jawOpen": 0.15, "tongueOut": 0.35, "mouthLowerDownLeft": 0.1, "mouthLowerDownRight": 0.1},
    "DD": {"jawOpen": 0.2, "mouthStretchLeft": 0.15, "mouthStretchRight": 0.15},
    "kk": {"jawOpen": 0.25, "mouthStretchLeft": 0.1, "mouthStretchRight": 0.1},
    "CH": {"jawOpen": 0.15, "mouthFunnel": 0.45, "mouthShrugUpper": 0.2},
    "SS": {"jawOpen": 0.1, "mouthStretchLeft": 0.35, "mouthStretchRight": 0.35},
    "nn": {"jawOpen": 0.18, "mouthLowerDownLeft": 0.1, "mouthLowerDownRight": 0.1},
    "RR": {"jawOpen": 0.2, "mouthFunnel": 0.3, "mouthPucker": 0.2},
    "aa": {"jawOpen": 0.7, "mouthLowerDownLeft": 0.3, "mouthLowerDownRight": 0.3},
    "E": {"jawOpen": 0.4, "mouthStretchLeft": 0.3, "mouthStretchRight": 0.3, "mouthSmileLeft": 0.15,
          "mouthSmileRight": 0.15},
    "ih": {"jawOpen": 0.25, "mouthStretchLeft": 0.35, "mouthStretchRight": 0.35, "mouthSmileLeft": 0.2,
           "mouthSmileRight": 0.2},
    "oh": {"jawOpen": 0.45, "mouthFunnel": 0.6, "mouthPucker": 0.2},
    "ou": {"jawOpen": 0.2, "mouthPucker": 0.8, "mouthFunnel": 0.3},
}
assert set(VISEME_ARKIT) == set(VISEME_NAMES)


def viseme_arkit_matrix() -> np.ndarray:
    """(15, 52) float32: row v = viseme v's ARKit weights; ``arkit_mouth = visemes @ matrix``."""
    m = np.zeros((len(VISEME_NAMES), len(ARKIT_NAMES)), dtype=np.float32)
    for i, v in enumerate(VISEME_NAMES):
        for k, w in VISEME_ARKIT[v].items():
            m[i, ARKIT_NAMES.index(k)] = w
    return m
