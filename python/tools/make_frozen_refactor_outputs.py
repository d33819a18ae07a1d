"""Writes python/tests/data/frozen_onsets_skeleton.npz: the outputs of the onset detectors
(eval/metrics.py, data/synth.py), the forward kinematics and a short synthetic motion on the fixed inputs of
python/tests/frozen_inputs.py. Run ONCE, on the code as it was before the two onset detectors, the two FK
walks and the hand-written rotations were merged (commit 2f21d8d); python/tests/test_refactor_frozen.py
checks the merged code against it. Re-running it now would only compare the code with itself.

    PYTHONPATH=python python python/tools/make_frozen_refactor_outputs.py python/tests/data/frozen_onsets_skeleton.npz
"""
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
from livegesture.data import synth_motion, synth_speech
from livegesture.eval import metrics as M
from livegesture import skeleton
from frozen_inputs import fixed_audio, fixed_poses

out = {}
x16 = fixed_audio(16000)
x22 = fixed_audio(22050)
out["metrics_onsets_16k"] = M.detect_onsets(x16, 16000)
out["metrics_onsets_22k"] = M.detect_onsets(x22, 22050)
out["metrics_onsets_16k_db"] = M.detect_onsets(x16, 16000, log_gain=None)
env, t = M.onset_strength(x16, 16000)
out["metrics_env_16k"], out["metrics_env_times_16k"] = env, t
an = synth_motion.analyse_audio(x16)
for k in ("times", "env", "active", "onset_env", "f0", "onsets", "onset_strength", "phrase_start"):
    out["synth_" + k] = getattr(an, k)
out["synth_onset_times"] = synth_motion.onset_times(x16)
T = 150
poses, trans, expr = synth_motion.generate_motion(an, T, synth_speech.STYLE_BY_SPEAKER[2], np.random.default_rng(7))
out["synth_poses"], out["synth_trans"] = poses, trans
p, tr = fixed_poses()
J, G = skeleton.forward_kinematics(p, tr, return_rotations=True)
out["fk_joints"], out["fk_rots"] = J, G
out["rest_joints"] = skeleton.rest_joints()
for k, v in out.items():
    print(k, np.shape(v))
np.savez_compressed(sys.argv[1], **out)
