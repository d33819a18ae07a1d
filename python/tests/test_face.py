"""The face channel (docs/face.md, issue 41): names and orders, the viseme head's causality and step/offline
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


def test_blinks_are_seeded_and_shaped():
    from livegesture.face.blink import BLINK, blinks

    b = blinks(0, 600)
    # the same peaks as runtime/src/face/tests.rs (the Rust process must match)
    assert np.nonzero(b > 0.99)[0].tolist() == [39, 110, 226, 314, 374, 510]
    assert abs(b[36] - 0.38268343) < 1e-6
    assert ((b >= 0) & (b <= 1)).all()
    assert not np.array_equal(b, blinks(1, 600))
    gaps = np.diff(np.nonzero(b > 0.99)[0])
    assert gaps.min() >= BLINK["gap_lo"] and gaps.max() <= BLINK["gap_hi"]


def test_export_into_a_bundle_and_refusals(tmp_path):
    import json

    from livegesture.face import export as X

    b = tmp_path / "b"
    (b / "reference").mkdir(parents=True)
    fr = {"sample_rate": 16000, "fps": 30, "frames_per_token": 4, "mel_frames_per_token": 8, "n_mels": 64}
    (b / "manifest.json").write_text(json.dumps({"frontend": fr, "graphs": [], "files": {}, "checks": {},
                                                 "reference": {"graphs": {}}}))
    m = X.add_to_bundle(SHIPPED, b, log=lambda *_: None)
    assert [g["name"] for g in m["graphs"]] == ["face"]
    assert m["checks"]["face"]["ort_vs_torch_max_abs"] <= 1e-5 * max(1.0, m["checks"]["face"]["ort_vs_torch_scale"])
    assert set(m["files"]) == {"face.onnx", "reference/face.npz"} and (b / "face.onnx").exists()
    assert m["face"]["visemes"] == list(VISEME_NAMES) and m["face"]["arkit"] == list(ARKIT_NAMES)
    z = np.load(b / "reference" / "face.npz")
    assert int(z["n_steps"]) == 10 and z["step0.output.visemes"].shape == (2, 4, 15)
    # again: the face graph is replaced, not added twice
    m = X.add_to_bundle(SHIPPED, b, log=lambda *_: None)
    assert [g["name"] for g in m["graphs"]] == ["face"]
    # a bundle on another frontend is refused, and left as it was
    bad = tmp_path / "bad"
    bad.mkdir()
    before = json.dumps({"frontend": {**fr, "n_mels": 80}, "graphs": [], "files": {}})
    (bad / "manifest.json").write_text(before)
    with pytest.raises(X.FaceExportError, match="n_mels"):
        X.add_to_bundle(SHIPPED, bad, log=lambda *_: None)
    assert (bad / "manifest.json").read_text() == before and not (bad / "face.onnx").exists()
    assert X.main(["--checkpoint", str(SHIPPED), "--bundle", str(tmp_path / "none")]) == 1


def test_npz_face_check_refuses_bad_files(tmp_path):
    T = 5
    good = {"poses": np.zeros((T, 165), np.float32), "arkit": np.full((T, 52), 0.5, np.float32),
            "arkit_names": np.array(ARKIT_NAMES), "visemes": np.full((T, 15), 1 / 15, np.float32),
            "viseme_names": np.array(VISEME_NAMES)}
    E.check_npz_face("x.npz", good)
    for key, val, msg in [("arkit", np.full((T, 52), 1.5, np.float32), "outside"),
                          ("visemes", np.full((T, 15), 0.1, np.float32), "sum to 1"),
                          ("arkit_names", np.array(ARKIT_NAMES[::-1]), "arkit_names"),
                          ("visemes", np.full((T, 14), 1 / 14, np.float32), "expected")]:
        with pytest.raises(ValueError, match=msg):
            E.check_npz_face("x.npz", {**good, key: val})
    with pytest.raises(KeyError, match="'visemes'"):
        E.check_npz_face("x.npz", {k: v for k, v in good.items() if k != "visemes"})
