"""``hil --clock sim`` assembles each trial from the plant's half and the controller's records:
the assembly must give, field for field, what the in-process learning run computes."""

from __future__ import annotations

import json

from controller.daemon.run import step_dict
from hil.experiments import learn
from hil.session.simsession import CONTROLLER_FIELDS, fill_from_records


def _reflex_dict(r) -> dict:
    # what the daemon writes for a reflex (controller/daemon/run.py), weights left out
    return {"kind": "reflex", "reflex": r.kind, "t_s": r.t_s, "cause": r.cause, "swing": r.swing, "phase": r.phase}


def test_records_assembled_by_simulated_time_give_the_in_process_trials():
    run = learn.LearningRun(learn.LearnConfig(trials=6, seed=5))
    times, trials = [], []
    try:
        run.bring_up()
        for i in range(6):
            trials.append(run.trial(i))
            times.append(dict(run.last_times))
        loop = run.ls.loop
        # the records as the daemon writes them (JSON lines), read back
        records = {"step": [json.loads(json.dumps(step_dict(s))) for s in loop.stats.steps],
                   "reflex": [json.loads(json.dumps(_reflex_dict(r))) for r in loop.stats.reflexes]}
    finally:
        run.close()
    assert any(t["reflexes"] for t in trials)  # the case the reflex rule is for
    assert any(t["gated_decisions"] for t in trials)
    for trial, t in zip(trials, times):
        plant_half = {k: ([] if isinstance(v, list) else 0) if k in CONTROLLER_FIELDS else v for k, v in trial.items()}
        rebuilt = fill_from_records(plant_half, t, records)
        assert json.dumps(rebuilt) == json.dumps(trial)  # every field, in the same order


def test_a_step_at_the_trial_s_first_instant_is_the_previous_trial_s():
    t = {"t0_s": 1.0, "crossing_s": 2.0, "end_s": 3.0}
    step = {"onset_s": 1.0, "burst_s": 0.3, "swing_start_s": 1.2, "gated_range_m": 0.5, "cell": 3,
            "modulation_s": 0.01, "amplitude": 1.0, "context": 0}
    late = {**step, "onset_s": 2.9, "swing_start_s": 3.1, "burst_s": 0.4}  # its swing began after the end
    out = fill_from_records({"reflexes": []}, t, {"step": [step, late], "reflex": []})
    assert out["burst_s"] == [] and out["gated_cells"] == []
    out = fill_from_records({"reflexes": []}, t, {"step": [{**step, "onset_s": 1.002}], "reflex": []})
    assert out["burst_s"] == [0.3] and out["gated_cells"] == [3] and out["gated_decisions"] == 1
