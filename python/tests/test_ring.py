"""Ring caches with a cohort phase (livegesture.forms.ring): every component stepped on ring caches equals the
shift layout's step within docs/parity.md's 1e-5 (scaled) over chained steps longer than every window, from a
cold start at any phase, after a stream joins at another phase, and the check fails when an entry is written
into the wrong slot."""
import pytest
import torch

from livegesture.forms.experts_fused import FusedExperts
from livegesture.forms.ring import RingStep, to_phase, write_entries
from livegesture.regions import REGION_NAMES

from helpers import scrambled_model

BOUND = 1e-5
BATCH = 3


@pytest.fixture(scope="module")
def model():
    return scrambled_model("tiny", seed=7)


def _components(model):
    """(name, shift component, step inputs maker)."""
    cfg = model.cfg
    R = len(REGION_NAMES)

    def expert_inputs(g, fused):
        shape = (BATCH, R) if fused else (BATCH,)
        return (torch.randint(0, cfg.codebook_size, shape, generator=g), torch.randn(BATCH, cfg.audio_dim, generator=g),
                torch.tensor([1.0, 0.0, 1.0]))

    def fusion_inputs(g):
        return ({r: torch.randn(BATCH, cfg.d_model, generator=g) for r in REGION_NAMES},
                torch.randn(BATCH, cfg.audio_dim, generator=g), torch.tensor([1.0, 0.0, 1.0]))

    fused = FusedExperts([model.experts[r] for r in REGION_NAMES]).eval()
    return [("experts_fused", fused, lambda g: expert_inputs(g, True), {}),
            ("expert_upper", model.experts["upper"], lambda g: expert_inputs(g, False), {}),
            ("fusion", model.fuse, fusion_inputs, {}),
            ("fusion_attention", model.fuse, fusion_inputs, {"attention_op": True})]


def _scale_err(a, b):
    return float((a - b).abs().max()) / max(1.0, float(b.abs().max()))


def _run(model, name, comp, inputs, kw, steps, phase0, join_at=None, wrong_slot=False):
    """Steps the shift component and its ring copy side by side; returns the worst scaled error of the data
    outputs and of the caches (ring caches rotated back to phase 0)."""
    ring = RingStep(comp)
    g = torch.Generator().manual_seed(3)
    shift_cache = comp.init_cache(BATCH)
    ring_cache = ring.init_cache(BATCH)
    phase = phase0
    worst_out, worst_cache = 0.0, 0.0
    with torch.no_grad():
        for t in range(steps):
            if join_at is not None and t == join_at:
                # the stream joins a cohort at another phase: its caches (shift layout = phase 0) rotated in
                phase = phase0 + 11
                ring_cache = to_phase(shift_cache, 0, phase)
            x = inputs(g)
            out_s, shift_cache = comp.step(*x, shift_cache, **kw)
            if join_at is not None and t < join_at:
                continue
            out_r, new = ring.step(*x, cache=ring_cache, phase=phase, **kw)
            ring_cache = write_entries(ring_cache, new, phase + (1 if wrong_slot else 0))
            phase += 1
            for k in out_s:
                worst_out = max(worst_out, _scale_err(out_r[k], out_s[k]))
            back = to_phase(ring_cache, phase, 0)
            for k in shift_cache:
                if k == "step":
                    assert torch.equal(back[k], shift_cache[k]), f"{name}: step differs at {t}"
                else:
                    worst_cache = max(worst_cache, _scale_err(back[k], shift_cache[k]))
    return worst_out, worst_cache


def test_ring_steps_equal_the_shift_layout(model):
    steps = 2 * max(model.cfg.history, model.cfg.audio_window, model.cfg.fuse_window) + 3
    for name, comp, inputs, kw in _components(model):
        for phase0 in (0, 4, 1000):
            out, cache = _run(model, name, comp, inputs, kw, steps, phase0)
            assert out <= BOUND and cache <= BOUND, f"{name} at phase {phase0}: outputs {out:.2e}, caches {cache:.2e}"


def test_a_stream_joining_at_another_phase(model):
    steps = 2 * max(model.cfg.history, model.cfg.audio_window, model.cfg.fuse_window) + 3
    for name, comp, inputs, kw in _components(model):
        out, cache = _run(model, name, comp, inputs, kw, steps, 3, join_at=9)
        assert out <= BOUND and cache <= BOUND, f"{name}: outputs {out:.2e}, caches {cache:.2e}"


def test_an_entry_in_the_wrong_slot_fails(model):
    steps = 2 * max(model.cfg.history, model.cfg.audio_window, model.cfg.fuse_window) + 3
    for name, comp, inputs, kw in _components(model):
        out, _ = _run(model, name, comp, inputs, kw, steps, 2, wrong_slot=True)
        assert out > 100 * BOUND, f"{name}: a wrong write slot went unnoticed ({out:.2e})"


def test_write_entries_refuses_an_entry_of_another_shape():
    cache = {"step": torch.zeros(2, dtype=torch.int64), "a.k": torch.zeros(2, 4, 5, 8)}
    with pytest.raises(ValueError, match=r"ring entry 'a.k': shape \(2, 4, 5, 8\) is not one slot"):
        write_entries(cache, {"step": torch.ones(2, dtype=torch.int64), "a.k": torch.zeros(2, 4, 5, 8)}, 0)
