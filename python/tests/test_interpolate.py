"""WiSE-FT interpolation (livegesture.interpolate): alpha 0 / 1 give the base / tuned weights exactly, 0.5 the
midpoint; tokenizer and statistics stay; a pair that was not made by fine-tuning is refused."""
import pytest
import torch

from livegesture import checkpoint as ckpt
from livegesture.interpolate import interpolate, main


@pytest.fixture()
def pair(tmp_path):
    base = ckpt.random_model("tiny", seed=0)
    tuned = ckpt.random_model("tiny", seed=0)
    with torch.no_grad():                       # a "fine-tuning": audio side moved, tokenizer kept
        for n, p in tuned.named_parameters():
            if not n.startswith("svq."):
                p.add_(torch.randn_like(p))
    ckpt.save(base, tmp_path / "base.pt")
    ckpt.save(tuned, tmp_path / "tuned.pt")
    return tmp_path / "base.pt", tmp_path / "tuned.pt"


def test_endpoints_and_midpoint(pair, tmp_path):
    base, tuned = pair
    sb, st = ckpt.load(base).state_dict(), ckpt.load(tuned).state_dict()
    moved = [k for k in sb if not torch.equal(sb[k], st[k])]
    assert moved and not any(k.startswith("svq.") for k in moved)
    for alpha, want in ((0.0, sb), (1.0, st)):
        m, _ = interpolate(base, tuned, alpha)
        assert all(torch.equal(v, want[k]) for k, v in m.state_dict().items())
    main(["--base", str(base), "--tuned", str(tuned), "--alpha", "0.5", "--out", str(tmp_path / "mid.pt")])
    mid = ckpt.load(tmp_path / "mid.pt")
    sm = mid.state_dict()
    for k in moved:
        torch.testing.assert_close(sm[k], (sb[k] + st[k]) / 2)
    assert mid.provenance["interpolation"]["alpha"] == 0.5


def test_refuses_pair_with_other_tokenizer(pair, tmp_path):
    base, _ = pair
    other = ckpt.random_model("tiny", seed=1)
    ckpt.save(other, tmp_path / "other.pt")
    with pytest.raises(ValueError, match="motion tokenizer or statistics differ"):
        interpolate(base, tmp_path / "other.pt", 0.5)
    with pytest.raises(ValueError, match="must lie in"):
        interpolate(base, base, 1.5)


def test_uniform_soup_of_several_tuned(pair, tmp_path):
    base, tuned = pair
    t2 = ckpt.load(tuned)
    with torch.no_grad():
        for n, p in t2.named_parameters():
            if not n.startswith("svq."):
                p.mul_(-1.0)
    ckpt.save(t2, tmp_path / "tuned2.pt")
    st, st2 = ckpt.load(tuned).state_dict(), t2.state_dict()
    soup, prov = interpolate(base, [tuned, tmp_path / "tuned2.pt"], 1.0)
    for k, v in soup.state_dict().items():
        torch.testing.assert_close(v, (st[k] + st2[k]) / 2)
    assert len(prov["interpolation"]["tuned"]) == 2
