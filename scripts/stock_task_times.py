"""Step time of ManiSkill's own dexterous tasks, stock and with GaussTac pads (make_tactile):
median of 20 random steps after 3, seed 0, obs_mode state_dict, the default grid; prints one row
per task: [task, "stock", ms, peak pad force N, "tactile", ms, peak pad force N].

    GAUSSTAC_COMPILE=fast python scripts/stock_task_times.py
"""
import time, warnings, statistics
warnings.simplefilter("ignore")
import gymnasium as gym, numpy as np, torch
import gausstac_maniskill as gm
import mani_skill.envs  # noqa
for env_id in ["RotateSingleObjectInHandLevel0-v1", "RotateValveLevel0-v1", "TriFingerRotateCubeLevel0-v1"]:
    row = [env_id]
    for label, make in (("stock", lambda: gym.make(env_id, obs_mode="state_dict")),
                        ("tactile", lambda: gm.make_tactile(env_id, obs_mode="state_dict"))):
        env = make(); env.reset(seed=0); env.action_space.seed(0)
        for _ in range(3): env.step(env.action_space.sample())
        ts = []; peak = 0.0
        for _ in range(20):
            t = time.perf_counter(); obs, *_ = env.step(env.action_space.sample()); ts.append(time.perf_counter() - t)
            if "tactile" in obs: peak = max(peak, max(float(m["force"].sum()) for m in obs["tactile"].values()))
        row += [label, round(1e3 * statistics.median(ts), 1), round(peak, 3)]
        env.close()
    print(row, flush=True)
