"""The face channel (SPEC 17, issue 41): names and orders, the viseme head's causality and step/offline
equality, the lip-sync metrics (with must-fail cases) and the shipped head's bounds on held-out speech."""
from pathlib import Path

import numpy as np
import pytest
import torch

from livegesture.face import evaluate as E
from livegesture.face.head import FaceConfig, VisemeHead
from livegesture.face.names import (ARKIT_NAMES, PHONE_TO_VISEME, VISEME_MOUTH, VISEME_NAMES, phone_mouth,
                                    phone_viseme, viseme_arkit_matrix)

ROOT = Path(__file__).resolve().parents[2]
SHIPPED = ROOT / "models" / "face.train" / "face.pt"


def test_names_and_orders():
    assert len(ARKIT_NAMES) == 52 and ARKIT_NAMES[0] == "eyeBlinkLeft" and ARKIT_NAMES[-1] == "tongueOut"
    assert ARKIT_NAMES.index("jawOpen") == 17 and ARKIT_NAMES.index("browInnerUp") == 43
    assert VISEME_NAMES == ("sil", "PP", "FF", "TH", "DD", "kk", "CH", "SS", "nn", "RR", "aa", "E", "ih", "oh", "ou")
    assert [MOUTH for MOUTH in VISEME_MOUTH.tolist()] == [0, 1, 5, 5, 5, 5, 5, 5, 5, 5, 2, 4, 4, 3, 3]
    assert phone_viseme("+SPN+") == 0 and phone_viseme("m") == 1 and phone_viseme("AO") == 10
    assert phone_mouth("AO") == 2 and phone_mouth("W") == 3 and phone_mouth("Y") == 4 and phone_mouth("HH") == 5
    with pytest.raises(ValueError, match="unknown phone 'QQ'"):
        phone_viseme("QQ")
    # every phone's viseme falls in the phone's own mouth class where the class has visemes
    for p in PHONE_TO_VISEME:
        m = phone_mouth(p)
        if m != 5:
            assert VISEME_MOUTH[phone_viseme(p)] == m, p
    t = viseme_arkit_matrix()
    assert t.shape == (15, 52) and (t >= 0).all() and (t <= 1).all()
    assert t[VISEME_NAMES.index("aa"), 17] > t[VISEME_NAMES.index("PP"), 17]


def _head(seed=0):
    torch.manual_seed(seed)
    h = VisemeHead(FaceConfig())
    h.mel_std.fill_(4.0)
    return h.eval()


def test_step_equals_offline_and_is_causal():
    h = _head()
    mel = torch.randn(2, 8 * 12, 64) * 4
    with torch.no_grad():
        off = h.outputs(h(mel))
        cache, steps = h.init_cache(2), []
        for t in range(12):
            o, cache = h.step(mel[:, 8 * t:8 * t + 8], cache)
            steps.append(o)
        for k in ("visemes", "arkit_mouth"):
            st = torch.cat([s[k] for s in steps], 1)
            assert (st - off[k]).abs().max().item() <= 1e-5
        assert torch.allclose(off["visemes"].sum(-1), torch.ones(2, 48), atol=1e-5)
        assert (off["arkit_mouth"] >= 0).all() and (off["arkit_mouth"] <= 1).all()
        # change only the audio after token 6: frames of tokens 0..6 do not change, later ones do
        mel2 = mel.clone()
        mel2[:, 8 * 7:] = torch.randn_like(mel2[:, 8 * 7:]) * 4
        off2 = h.outputs(h(mel2))["visemes"]
        assert torch.equal(off2[:, :28], off["visemes"][:, :28])
        assert (off2[:, 28:] - off["visemes"][:, 28:]).abs().max() > 1e-3


def test_step_refuses_wrong_shapes():
    h = _head()
    with pytest.raises(ValueError, match="mel"):
        h.step(torch.zeros(1, 7, 64), h.init_cache(1))


def test_metrics_and_must_fail():
    assert E.macro_f1(np.array([0, 1, 2, 2]), np.array([0, 1, 2, 2])) == 1.0
    assert E.macro_f1(np.array([0, 1]), np.array([1, 0])) == 0.0
    assert E.auc(np.array([2.0, 3.0]), np.array([0.0, 1.0])) == 1.0
    assert E.auc(np.array([1.0]), np.array([1.0])) == 0.5
    assert np.isnan(E.auc(np.array([1.0]), np.array([])))
    rng = np.random.default_rng(0)
    n = 300
    phones = list(rng.choice(["SIL", "M", "AA", "UW", "IY", "S"], n))
    audio = rng.normal(0, 0.1, n * 16000 // 30 + 10)
    truth = {"SIL": "sil", "M": "PP", "AA": "aa", "UW": "ou", "IY": "ih", "S": "SS"}
    vis = np.zeros((n, 15))
    vis[np.arange(n), [VISEME_NAMES.index(truth[p]) for p in phones]] = 1.0
    ark = vis @ viseme_arkit_matrix()
    good = E.evaluate([{"name": "x", "phones": phones, "visemes": vis, "arkit": ark, "audio": audio}])
    assert good["mean"]["viseme_macro_f1"] == 1.0 and good["mean"]["jawopen_auc"] == 1.0
    assert E.failures(good) == []
    # the same frames shifted by 3 frames: the reported lag finds them
    lag = E.evaluate([{"name": "x", "phones": phones[:-3], "visemes": np.roll(vis, 3, 0)[:-3],
                       "arkit": np.roll(ark, 3, 0)[:-3], "audio": audio}])
    assert lag["lags_frames"]["viseme_macro_f1"] == 3 and lag["mean"]["viseme_macro_f1"] == 1.0
    # must fail: constant output
    flat = np.tile(np.eye(15)[0], (n, 1))
    bad = E.evaluate([{"name": "x", "phones": phones, "visemes": flat, "arkit": flat @ viseme_arkit_matrix(),
                       "audio": audio}])
    assert len(E.failures(bad)) == 2
    with pytest.raises(ValueError, match="non-finite"):
        E.evaluate([{"name": "x", "phones": phones, "visemes": vis * np.nan, "arkit": ark, "audio": audio}])
    with pytest.raises(ValueError, match=r"expected \(300, 15\)"):
        E.evaluate([{"name": "x", "phones": phones, "visemes": vis[:10], "arkit": ark, "audio": audio}])


def test_shipped_head_loads_and_matches_its_report():
    """The shipped checkpoint exists and its committed report holds the bounds (the full measurement on
    held-out real speech runs in the test command's face stage)."""
    import json

    from livegesture.face.train import load_head

    h = load_head(SHIPPED)
    assert isinstance(h, VisemeHead)
    rep = json.loads((SHIPPED.parent / "eval.json").read_text())
    assert E.failures(rep) == []
    assert len(rep["recordings"]) == 8
