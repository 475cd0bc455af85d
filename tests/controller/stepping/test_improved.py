"""The improved learner (controller.stepping.improved): the paper's gate, memory and rule, with
context, credit over neighbouring cells that fades, the too-close rule and the learned lift."""

from __future__ import annotations

import math

import numpy as np
import pytest

from controller.motion.gait import GaitConfig, tuck_fraction
from controller.stepping.improved import ImprovedConfig, ImprovedPremotor
from controller.stepping.reflexes import Reflex

BASE = 0.3


def TUCK(amplitude: float) -> float:
    """The gait's own tuck fraction at its default settings: the half-sine up to a lift of 3.0,
    fully tucked at 3.44 (the method's builder hands the learner the same function)."""
    return tuck_fraction(GaitConfig(), amplitude)


def premotor(**config) -> ImprovedPremotor:
    """The rules before round 8 alone unless asked: no context starts tucked, no commitment, and
    none of round 15's rules for the contexts that learn their lift (here every context)."""
    return ImprovedPremotor(4, 28, BASE, ImprovedConfig(**{"tucked_contexts": 0, "commit_earlier_s": 0.0,
                                                           "settle_lifting": 0.0, "tucked_keeps_burst": False,
                                                           **config}))


def reflex(kind: str, t_s: float, cause: str = "foot_on_top", swing: bool = True, phase: float = 0.9) -> Reflex:
    return Reflex(kind, t_s, cause, swing, phase)


def test_the_memory_is_one_hot_but_the_credit_reaches_the_neighbours():
    p = premotor(spread_cells=1.5, stm_tau_s=1.0, context_share=0.0)
    p.weights[1, 10], p.weights[1, 11] = 0.2, 0.3
    p.on_step_onset(0.0, 10, context=1)
    assert p.burst_s(0.0) == pytest.approx(BASE + 0.2)  # only the gated cell's weight drives the burst
    assert p.burst_s(1.0) == pytest.approx(BASE + 0.2 * math.exp(-1.0))
    traces = p.traces.at(0.0).reshape(4, 28)
    assert traces[1, 10] == 1.0
    assert traces[1, 11] == pytest.approx(math.exp(-1 / (2 * 1.5 ** 2)))
    assert traces[1, 15] > 0.0 and traces[1, 16] == 0.0  # up to 3 widths away (4.5 cells: 5)
    assert traces[0].sum() == 0.0 and traces[2].sum() == 0.0  # another context is untouched (no sharing)


def test_extension_lengthens_placement_shortens_the_traced_weights_within_the_bound():
    p = premotor(spread_cells=0.0, learning_rate_s=0.3, weight_limit_s=0.4, context_share=0.0)
    p.on_step_onset(0.0, 5, context=0)
    p.on_reflex("extension", 0.0)
    assert p.weights[0, 5] == pytest.approx(0.3) and np.count_nonzero(p.weights) == 1
    p.on_reflex("extension", 0.0)
    assert p.weights[0, 5] == pytest.approx(0.4)  # bounded
    p.on_reflex("placement", 0.0)
    assert p.weights[0, 5] == pytest.approx(0.1)
    with pytest.raises(ValueError, match="reflex kind"):
        p.on_reflex("sneeze", 0.0)


def test_the_neighbours_credit_fades_with_the_reflexes_and_with_their_own_training():
    p = premotor(spread_cells=1.0, spread_fade=2.0, spread_settle=1.0)
    first = []
    for _ in range(4):
        p.on_step_onset(p.traces.t_s + 100.0, 10, context=0)  # the old traces have decayed away
        first.append(float(p.traces.at(p.traces.t_s)[11]))
        p.on_reflex("extension", p.traces.t_s)
    assert first[0] == pytest.approx(math.exp(-0.5))
    assert first[1] < first[0] and first[2] < first[1]  # fewer credit as reflexes accumulate
    q = premotor(spread_cells=1.0, spread_fade=1000.0, spread_settle=1.0)
    q.on_step_onset(0.0, 11, context=0)
    q.on_reflex("extension", 0.0)  # cell 11 trained by its own mistake
    q.on_step_onset(100.0, 10, context=0)
    assert q.traces.at(100.0)[11] == pytest.approx(math.exp(-0.5) / (1.0 + 1.0), rel=1e-3)
    assert q.traces.at(100.0)[9] == pytest.approx(math.exp(-0.5), rel=1e-3)


def test_a_reflex_after_a_gate_that_saw_nothing_is_learnt_as_placement():
    p = premotor(spread_cells=0.0)
    p.on_step_onset(0.0, 3, context=0)
    p.on_step_onset(0.7, None, context=None)  # the crossing's gate: the obstacle nearer than any cell
    p.on_contact_reflex(reflex("extension", 1.2))  # the phase says extension
    assert p.weights[0, 3] < 0.0 and p.too_close == 1
    r = premotor(spread_cells=0.0)
    r.on_step_onset(0.0, 3, context=0)
    r.on_contact_reflex(reflex("extension", 0.5))  # the gate held a cell: the phase decides
    assert r.weights[0, 3] > 0.0 and r.too_close == 0
    q = premotor(spread_cells=0.0)
    q.on_step_onset(0.0, None, context=None)
    q.on_step_onset(0.7, None, context=None)  # two empty gates: after the obstacle, not too close
    q.on_contact_reflex(reflex("extension", 1.2))
    assert q.too_close == 0


def test_a_contact_on_the_way_up_raises_that_contexts_lift_up_to_the_leg_limit():
    p = premotor(lift_amplitude=1.9, lift_step=0.5, lift_max=2.6, lift_range_m=0.4)
    assert p.lift_amplitude(0.6, 2) == 1.0  # too far: no lift
    assert p.lift_amplitude(None, None) == 1.0
    assert p.lift_amplitude(0.3, 2) == 1.9
    p.on_contact_reflex(reflex("placement", 1.0, cause="shin", swing=True, phase=0.2))
    assert p.lifts.tolist() == [1.9, 1.9, 2.4, 1.9] and p.lift_raises == 1
    p.on_contact_reflex(reflex("placement", 3.0, cause="foot_in_air", swing=True, phase=0.3))
    assert p.lifts[2] == pytest.approx(2.6)  # capped at lift_max
    p.on_contact_reflex(reflex("placement", 5.0, cause="shin", swing=True, phase=0.3))
    assert p.lifts[2] == pytest.approx(2.6) and p.lift_raises == 2
    assert p.lift_amplitude(0.3, 2) == pytest.approx(2.6)
    for late in (reflex("extension", 7.0, cause="foot_on_top", swing=True, phase=0.95),   # landed on top
                 reflex("placement", 7.0, cause="shin", swing=False, phase=0.7)):         # stance: too close
        before = p.lifts.copy()
        p.lift_amplitude(0.3, 1)
        p.on_contact_reflex(late)
        assert (p.lifts == before).all()
    p.lift_amplitude(0.9, 1)  # a cycle that did not lift: a contact cannot be "too low"
    p.on_contact_reflex(reflex("placement", 9.0, cause="shin", swing=True, phase=0.2))
    assert p.lifts[1] == 1.9


def test_frozen_learns_nothing():
    p = premotor(learning=False)
    p.on_step_onset(0.0, 3, context=0)
    p.lift_amplitude(0.3, 0)
    p.on_contact_reflex(reflex("placement", 0.1, cause="shin", swing=True, phase=0.1))
    assert not p.weights.any() and (p.lifts == 1.9).all()


def test_bad_settings_and_contexts_are_refused():
    with pytest.raises(ValueError, match="lift_max"):
        ImprovedConfig(lift_amplitude=3.0, lift_max=2.0)
    with pytest.raises(ValueError, match="spread_cells"):
        ImprovedConfig(spread_cells=-1.0)
    with pytest.raises(ValueError, match="context"):
        premotor().on_step_onset(0.0, 3, context=9)
    with pytest.raises(ValueError, match="positive integers"):
        ImprovedPremotor(0, 28, BASE)


def test_a_reflex_asking_more_of_a_saturated_gate_asks_the_other_branch():
    p = premotor(spread_cells=0.0, weight_limit_s=0.5, flip_at=0.95, learning_rate_s=0.3)
    p.weights[0, 7] = 0.5  # the gate's weight at its bound: the swing was as long as it could be
    p.on_step_onset(0.0, 7, context=0)
    p.on_contact_reflex(reflex("extension", 0.9))  # landed on the block all the same
    assert p.weights[0, 7] == pytest.approx(0.5 - 0.3 * math.exp(-0.9 / p.config.trace_tau_s)) and p.flips == 1  # an extra step instead
    p.on_contact_reflex(reflex("extension", 2.0))  # below the bound now: the phase decides again
    assert p.weights[0, 7] > 0.5 - 0.3 * math.exp(-0.9 / p.config.trace_tau_s) and p.flips == 1
    q = premotor(spread_cells=0.0, flip_at=2.0)  # above 1: never
    q.weights[0, 7] = q.config.weight_limit_s
    q.on_step_onset(0.0, 7, context=0)
    q.on_contact_reflex(reflex("extension", 0.9))
    assert q.weights[0, 7] == q.config.weight_limit_s and q.flips == 0


def test_a_stance_reflex_is_judged_by_the_gate_whose_swing_landed_the_foot():
    """A foot landing on top of the block fires at touchdown, which is also the next step onset:
    the gate just taken (empty: the block is under the foot) drove nothing yet. The gate before
    it, the crossing's, held a cell: not "too close", and the phase's "extension" stands (tuning
    seed 76 collapsed when such landings were learnt as placement). For every stance reflex
    (``landing_gate``, off) or for a foot on top only (``landing_on_top``, the default)."""
    p = premotor(spread_cells=0.0, landing_gate=True)
    p.on_step_onset(0.0, 9, context=0)
    p.on_step_onset(0.7, 3, context=0)  # the crossing's gate
    p.on_step_onset(1.4, None, context=None)  # touchdown on the block: the next onset, empty
    p.on_contact_reflex(reflex("extension", 1.4, cause="foot_on_top", swing=False, phase=0.0))
    assert p.too_close == 0 and p.weights[0, 3] > 0.0
    q = premotor(spread_cells=0.0, landing_gate=True)
    q.on_step_onset(0.0, 3, context=0)
    q.on_step_onset(0.7, None, context=None)  # the crossing's gate saw nothing, the one before did
    q.on_step_onset(1.4, None, context=None)
    q.on_contact_reflex(reflex("extension", 1.45, cause="foot_on_top", swing=False, phase=0.05))
    assert q.too_close == 1 and q.weights[0, 3] < 0.0
    off = premotor(spread_cells=0.0, landing_on_top=False)  # both off: the last gate, empty: "too close"
    off.on_step_onset(0.0, 9, context=0)
    off.on_step_onset(0.7, 3, context=0)
    off.on_step_onset(1.4, None, context=None)
    off.on_contact_reflex(reflex("extension", 1.4, cause="foot_on_top", swing=False, phase=0.0))
    assert off.too_close == 1 and off.weights[0, 3] < 0.0


def test_the_other_branch_is_asked_of_the_landing_gate_at_its_bound():
    p = premotor(spread_cells=0.0, weight_limit_s=0.5, flip_at=0.95, landing_gate=True)
    p.weights[0, 3] = 0.5  # the crossing's gate already asks the longest swing
    p.on_step_onset(0.0, 3, context=0)
    p.on_step_onset(0.9, None, context=None)
    p.on_contact_reflex(reflex("extension", 0.9, cause="foot_on_top", swing=False, phase=0.0))
    assert p.flips == 1 and p.weights[0, 3] < 0.5


def test_a_tucked_lift_lengthens_that_cycles_burst_by_the_tuck():
    """A lift the gait tucks takes the longer burst of a high step, by the tuck fraction; the next
    gate that does not lift ends it."""
    p = ImprovedPremotor(4, 28, BASE, ImprovedConfig(lift_amplitude=1.9, lift_max=3.44, lift_range_m=0.4,
                                                     range_follows_tuck=False),
                         tuck=TUCK, tucked_extra_s=0.3)
    p.on_step_onset(0.0, 5, context=3)
    assert p.lift_amplitude(0.3, 3) == 1.9 and p.burst_s(0.0) == pytest.approx(BASE)  # not tucked: as before
    p.lifts[3] = 3.22
    p.on_step_onset(1.0, 4, context=3)
    assert p.lift_amplitude(0.3, 3) == pytest.approx(3.22)
    assert p.burst_s(1.0) == pytest.approx(BASE + 0.5 * 0.3)  # half tucked: half the extra
    p.on_step_onset(2.0, None, context=None)
    assert p.lift_amplitude(None, None) == 1.0 and p.burst_s(2.0) == pytest.approx(BASE)
    with pytest.raises(ValueError, match="tucked_extra_s"):
        ImprovedPremotor(4, 28, BASE, tucked_extra_s=-0.1)


def test_landing_on_top_judges_only_a_foot_on_the_block_by_the_gate_before():
    for cause, too_close in (("foot_on_top", 0), ("shin", 1)):
        p = premotor(spread_cells=0.0, landing_on_top=True)
        p.on_step_onset(0.0, 9, context=0)
        p.on_step_onset(0.7, 3, context=0)
        p.on_step_onset(1.4, None, context=None)
        p.on_contact_reflex(reflex("extension", 1.45, cause=cause, swing=False, phase=0.05))
        assert p.too_close == too_close, cause


def test_a_tucked_crossing_at_the_bound_is_not_flipped_when_flip_tucked_is_off():
    """A tucked swing already takes the CPG's longest burst: an extension asked of it is answered
    by the gates before it (the step before, longer), not by the other branch (``flip_tucked``)."""
    def tucked(flip_tucked: bool, lift: float) -> ImprovedPremotor:
        # fresh_beyond_edge off: cell 5's weight is set as if learnt once tucked, not before (rule 23
        # would clear it at the first gate, the lift range moving from 0.40 m to 0.20 m)
        p = ImprovedPremotor(4, 28, BASE, ImprovedConfig(spread_cells=0.0, flip_tucked=flip_tucked, lift_max=3.44,
                                                         fresh_beyond_edge=False),
                             tuck=TUCK, tucked_extra_s=0.3)
        p.lifts[3] = lift
        p.weights[3, 12], p.weights[3, 5] = -0.2, 0.5  # the step before short, the crossing's gate at its bound
        p.on_step_onset(0.0, 12, context=3)
        assert p.lift_amplitude(0.5, 3) == 1.0  # 0.5 m: beyond the lift's range (0.4 m), no tuck
        p.on_step_onset(0.7, 5, context=3)
        # the crossing: lifts (tucked above 3.0). Fully tucked, the context lifts within 0.20 m
        # (range_follows_tuck), so the gate sits inside that edge, not on it
        assert p.lift_amplitude(0.15, 3) > 1.0
        p.on_contact_reflex(reflex("extension", 1.3, cause="foot_on_top", swing=True, phase=0.84))
        return p

    kept = tucked(False, 3.44)
    assert kept.flips == 0 and kept.weights[3, 12] > -0.2  # the step before lengthens
    flipped = tucked(True, 3.44)  # flip_tucked on: rule 5 as before round 5
    assert flipped.flips == 1 and flipped.weights[3, 12] < -0.2
    untucked = tucked(False, 2.2)  # a half-sine crossing at its bound: still the other branch
    assert untucked.flips == 1 and untucked.weights[3, 12] < -0.2


def test_a_gate_shares_its_credit_with_the_other_heights_less_as_they_learn_their_own():
    p = premotor(spread_cells=0.0, context_share=0.5, spread_settle=1.0)
    p.on_step_onset(0.0, 10, context=1)
    traces = p.traces.at(0.0).reshape(4, 28)
    assert traces[1, 10] == 1.0 and traces[0, 10] == traces[2, 10] == traces[3, 10] == 0.5
    assert np.count_nonzero(traces) == 4  # the same cell only (no spread here)
    assert p.burst_s(0.0) == pytest.approx(BASE)  # the memory is the gated row's: nothing learnt yet
    p.on_reflex("extension", 0.0)
    assert p.weights[1, 10] == pytest.approx(0.3) and p.weights[2, 10] == pytest.approx(0.15)
    q = premotor(spread_cells=0.0, context_share=0.5, spread_settle=1.0)
    q.own_trained[2, 10] = 1.0  # context 2 has learnt from its own mistakes at this cell: half as much
    q.on_step_onset(0.0, 10, context=1)
    assert q.traces.at(0.0).reshape(4, 28)[2, 10] == pytest.approx(0.25)
    r = premotor(spread_cells=0.0, context_share=0.0)  # off: the other rows untouched
    r.on_step_onset(0.0, 10, context=1)
    assert np.count_nonzero(r.traces.at(0.0)) == 1


def test_a_cell_gated_for_the_first_time_starts_from_its_gated_neighbours():
    p = premotor(fill_new_cells=2.0, context_share=0.0)
    p.on_step_onset(0.0, 10, context=1)
    assert p.weights[1, 10] == 0.0 and p.filled == 0  # no neighbour gated yet: nothing to take
    p.on_step_onset(0.7, 12, context=1)
    p.on_step_onset(1.4, 12, context=1)
    assert p.filled == 1 and p.weights[1, 12] == 0.0  # cell 10, two away, was gated: its weight, 0
    p.weights[1, 10], p.weights[1, 12], p.weights[1, 14] = 0.1, 0.4, -0.5  # 14 never gated: not heard
    p.on_step_onset(2.1, 11, context=1)
    # cell 10 (gated once, 1 away) and cell 12 (gated twice, 1 away): by visits, the Gaussian equal
    assert p.weights[1, 11] == pytest.approx((0.1 * 1 + 0.4 * 2) / 3) and p.filled == 2
    p.weights[1, 11] = -0.2
    p.on_step_onset(2.8, 11, context=1)  # the second visit keeps what the cell learnt
    assert p.weights[1, 11] == -0.2 and p.filled == 2
    p.on_step_onset(3.5, 13, context=2)  # another context's row has no gated neighbours
    assert p.weights[2, 13] == 0.0
    off = premotor(context_share=0.0)  # the default: off
    off.on_step_onset(0.0, 12, context=1)
    off.weights[1, 12] = 0.4
    off.on_step_onset(0.7, 11, context=1)
    assert off.weights[1, 11] == 0.0 and off.filled == 0


def test_with_fade_gated_only_a_neighbour_never_gated_keeps_its_full_share():
    p = premotor(spread_cells=1.0, spread_fade=2.0, spread_settle=1.0, context_share=0.0, fade_gated_only=True)
    p.on_step_onset(0.0, 11, context=0)  # cell 11 gated once (and trained: its own reflex)
    p.on_reflex("extension", 0.0)
    p.on_step_onset(100.0, 9, context=0)
    p.on_reflex("extension", 100.0)  # two reflexes: the fade is 1 / (1 + 2 / 2) = 0.5
    p.on_step_onset(200.0, 10, context=0)
    traces = p.traces.at(200.0)
    own_11 = float(p.own_trained[0, 11])
    assert traces[11] == pytest.approx(0.5 * math.exp(-0.5) / (1.0 + own_11), rel=1e-3)  # gated before: faded
    assert traces[12] == pytest.approx(math.exp(-2.0), rel=1e-3)  # never gated: its full share
    q = premotor(spread_cells=1.0, spread_fade=2.0, spread_settle=1.0, context_share=0.0)  # the default
    q.on_step_onset(0.0, 11, context=0)
    q.on_reflex("extension", 0.0)
    q.on_step_onset(100.0, 9, context=0)
    q.on_reflex("extension", 100.0)
    q.on_step_onset(200.0, 10, context=0)
    assert q.traces.at(200.0)[12] == pytest.approx(0.5 * math.exp(-2.0), rel=1e-3)


def tuck_premotor(**config) -> ImprovedPremotor:
    settings = {"spread_cells": 0.0, "lift_amplitude": 3.44, "lift_max": 3.44, "lift_range_m": 0.4,
                "tucked_contexts": 0, "commit_earlier_s": 0.0, "range_follows_tuck": False, **config}
    return ImprovedPremotor(4, 28, BASE, ImprovedConfig(**settings),
                            tuck=TUCK, tucked_extra_s=0.3)


def test_a_tucked_swing_landing_on_top_shrinks_that_contexts_lift_range_to_its_gate():
    """learn_lift_range: the longest (tucked) swing came down on top, so its take-off was beyond
    a crossing's reach; that context lifts from nearer than the gate's range from now on."""
    p = tuck_premotor(learn_lift_range=True)
    p.on_step_onset(0.0, 7, context=1)
    assert p.lift_amplitude(0.30, 1) == pytest.approx(3.44)  # within 0.4 m: the tucked lift
    p.on_contact_reflex(reflex("extension", 0.9, cause="foot_on_top", swing=True, phase=0.95))
    assert p.lift_ranges[1] == pytest.approx(0.30) and p.range_shrinks == 1
    assert list(p.lift_ranges[[0, 2, 3]]) == [0.4, 0.4, 0.4]  # the other heights keep theirs
    p.on_step_onset(1.0, 7, context=1)
    assert p.lift_amplitude(0.305, 1) == 1.0 and p.burst_s(1.0) == pytest.approx(BASE + p.weights[1, 7])
    p.on_step_onset(2.0, 6, context=1)
    assert p.lift_amplitude(0.29, 1) == pytest.approx(3.44)
    # a landing in stance is judged by the gate whose swing landed it (rule 3): that gate's range
    p.on_step_onset(3.0, None, context=None)
    p.lift_amplitude(None, None)
    p.on_contact_reflex(reflex("extension", 3.05, cause="foot_on_top", swing=False, phase=0.05))
    assert p.lift_ranges[1] == pytest.approx(0.29) and p.range_shrinks == 2


def test_the_lift_range_stays_when_off_untucked_or_not_on_top():
    cases = ((dict(), 3.44, "foot_on_top"),  # learn_lift_range off (the default)
             (dict(learn_lift_range=True), 2.5, "foot_on_top"),  # a half-sine swing: not the longest
             (dict(learn_lift_range=True), 3.44, "shin"))  # struck, not landed on top
    for config, lift, cause in cases:
        p = tuck_premotor(**config)
        p.lifts[:] = lift
        p.on_step_onset(0.0, 7, context=1)
        p.lift_amplitude(0.30, 1)
        p.on_contact_reflex(reflex("extension", 0.9, cause=cause, swing=True, phase=0.95))
        assert list(p.lift_ranges) == [0.4] * 4 and p.range_shrinks == 0, (config, lift, cause)


def test_commit_earlier_moves_an_earlier_gates_weight_along_its_own_sign():
    """commit_earlier_s: either branch of the step before the judged one moves the take-off out of
    the gap between the branches, so a weight already on one keeps going; the judged gate's
    neighbourhood, and weights nearer 0 than the setting, learn from the reflex as before."""
    def run(commit: float) -> ImprovedPremotor:
        p = premotor(spread_cells=1.0, context_share=0.0, learning_rate_s=0.1, commit_earlier_s=commit)
        p.weights[0, 15], p.weights[0, 20] = -0.2, -0.05
        p.weights[0, 7] = -0.2  # beside the judged gate (6): within the spread's reach
        p.on_step_onset(0.0, 20, context=0)
        p.on_step_onset(0.7, 15, context=0)
        p.on_step_onset(1.4, 6, context=0)
        p.on_reflex("extension", 1.9)
        return p

    before = {(0, 15): -0.2, (0, 20): -0.05, (0, 7): -0.2, (0, 6): 0.0}
    off, on = run(0.0), run(0.1)
    for cell in before:
        assert off.weights[cell] > before[cell]  # the paper's rule: every traced weight lengthens
    assert on.weights[0, 15] < -0.2  # committed to the short branch: shorter still
    assert on.weights[0, 20] > -0.05  # too near 0 to count as a branch: as the reflex asks
    assert on.weights[0, 7] > -0.2 and on.weights[0, 6] == pytest.approx(off.weights[0, 6])


def test_commit_flip_turns_a_committed_weight_at_its_bound_to_the_other_branch():
    """commit_flip: an earlier gate whose branch was taken in full (at flip_at of the bound) and
    still failed takes the other branch at once; a weight gated too long ago is left alone."""
    def run(flip: bool, gated_at_s: float) -> ImprovedPremotor:
        p = premotor(spread_cells=0.0, context_share=0.0, learning_rate_s=0.1, commit_earlier_s=0.1,
                     commit_flip=flip, flip_at=0.95, weight_limit_s=0.5)
        p.weights[0, 19] = 0.5
        p.on_step_onset(gated_at_s, 19, context=0)
        p.on_step_onset(10.0, 7, context=0)
        p.on_reflex("extension", 10.6)
        return p

    assert run(False, 9.3).weights[0, 19] == pytest.approx(0.5)  # committed, at the bound: stays
    flipped = run(True, 9.3)
    assert flipped.weights[0, 19] == pytest.approx(-0.5) and flipped.flips == 1
    assert run(True, 0.0).weights[0, 19] == pytest.approx(0.5)  # gated 10 s before: not this failure's step


def test_the_low_contexts_start_tucked_and_share_credit_only_with_their_kind():
    """tucked_contexts: contexts below it start at lift_max and lift within their tucked range;
    credit is shared (context_share), and committed (rule 8), only between rows of one kind."""
    p = tuck_premotor(tucked_contexts=2, lift_amplitude=1.9, context_share=0.5)
    assert list(p.lifts) == [3.44, 3.44, 1.9, 1.9]
    assert list(p.lift_ranges) == pytest.approx([0.30, 0.30, 0.4, 0.4])
    p.on_step_onset(0.0, 7, context=1)
    assert p.lift_amplitude(0.31, 1) == 1.0 and p.lift_amplitude(0.29, 1) == pytest.approx(3.44)
    traces = p.traces.at(0.0).reshape(4, 28)
    assert traces[1, 7] == 1.0 and traces[0, 7] > 0.0 and traces[2, 7] == 0.0 and traces[3, 7] == 0.0
    p.on_step_onset(100.0, 7, context=3)  # the first gate's traces have decayed away
    traces = p.traces.at(100.0).reshape(4, 28)
    assert traces[2, 7] > 0.0 and traces[0, 7] < 0.01  # a tall context shares with the other tall one
    untucked = tuck_premotor(tucked_contexts=0, lift_amplitude=1.9)
    assert list(untucked.lifts) == [1.9] * 4 and list(untucked.lift_ranges) == [0.4] * 4


def test_commit_is_for_the_tucked_kind_when_some_contexts_start_tucked():
    def run(row: int) -> float:
        p = premotor(spread_cells=0.0, context_share=0.0, learning_rate_s=0.1, commit_earlier_s=0.1,
                     tucked_contexts=2, lift_max=3.44)
        p.weights[row, 15] = -0.2
        p.on_step_onset(0.0, 15, context=row)
        p.on_step_onset(0.7, 6, context=row)
        p.on_reflex("extension", 1.2)
        return float(p.weights[row, 15])

    assert run(1) < -0.2  # a tucked context: committed to the short branch
    assert run(3) > -0.2  # a context that learns its lift: the reflex's ask, as before round 8


def test_a_tucked_context_lifts_within_a_time_to_contact_at_the_believed_speed():
    """tucked_time_s is a time: at 0.6 m/s the tucked contexts lift from 0.36 m, at 0.5 from 0.30."""
    def ranges(speed: float) -> list[float]:
        p = ImprovedPremotor(4, 28, BASE, ImprovedConfig(tucked_contexts=2, lift_max=3.44), ground_speed_m_s=speed)
        return p.lift_ranges.tolist()

    assert ranges(0.5) == [0.30, 0.30, 0.4, 0.4]  # exactly: 0.60 s (rule 24, round 25) at 0.5 m/s
    assert ranges(0.6) == pytest.approx([0.36, 0.36, 0.4, 0.4])
    with pytest.raises(ValueError, match="ground_speed_m_s"):
        ImprovedPremotor(4, 28, BASE, ground_speed_m_s=0.0)


def test_the_ground_speed_is_the_belief_fused_with_each_measured_closing_speed():
    """Each closing speed is weighted by its inverse variance, the belief by 1 / sd^2; the
    tucked contexts' range is their time to contact at the fused speed, the others' stays in
    metres."""
    p = ImprovedPremotor(4, 28, BASE, ImprovedConfig(tucked_contexts=2, lift_max=3.44, speed_belief_sd_m_s=0.05))
    p.observe_closing_speed(0.6, 0.05 ** 2)  # as sure as the belief: halfway
    assert p.ground_speed_m_s == pytest.approx(0.55)
    for _ in range(400):
        p.observe_closing_speed(0.55, 0.01 ** 2)
    assert p.ground_speed_m_s == pytest.approx(0.55, abs=1e-9)

    def lifts(range_m: float, context: int) -> bool:
        return p.lift_amplitude(range_m, context) > 1.0

    assert lifts(0.35, 0) and not lifts(0.36, 0)  # 0.60 s at 0.55 m/s: 0.33 m, + 0.5 s x 0.05 m/s (rule 24)
    assert lifts(0.39, 3) and not lifts(0.41, 3)  # a context that learns its lift: 0.40 m, as set
    for bad in ((math.nan, 1e-4), (0.5, 0.0), (0.5, math.inf), (math.inf, 1e-4)):
        p.observe_closing_speed(*bad)  # ignored
    assert p.ground_speed_m_s == pytest.approx(0.55, abs=1e-9)


def test_with_no_doubt_of_the_belief_no_measurement_moves_it():
    p = ImprovedPremotor(4, 28, BASE, ImprovedConfig(tucked_contexts=2, lift_max=3.44, speed_belief_sd_m_s=0.0))
    p.observe_closing_speed(0.6, 1e-6)
    assert p.ground_speed_m_s == 0.5
    assert p.lift_amplitude(0.299, 0) > 1.0 and p.lift_amplitude(0.301, 0) == 1.0


def test_a_context_that_learns_its_lift_lifts_nearer_as_its_swing_tucks():
    """range_follows_tuck: the range moves from lift_range_m (0.40 m) to the context's
    tucked_time_s of contact (here 0.4 s at 0.5 m/s: 0.20 m) by the tuck fraction of its lift."""
    def tuck(amplitude: float) -> float:
        return min(1.0, max(0.0, (amplitude - 3.0) / 0.4))

    config = ImprovedConfig(tucked_contexts=2, lift_max=3.4, tucked_time_s=(0.56, 0.56, 0.48, 0.4),
                            range_follows_tuck=True)
    p = ImprovedPremotor(4, 28, BASE, config, tuck=tuck)

    def lifts(range_m: float) -> bool:
        return p.lift_amplitude(range_m, 3) > 1.0

    assert lifts(0.39) and not lifts(0.41)  # the hardwired lift (1.9): no tuck, 0.40 m
    p.lifts[3] = 3.2  # half tucked: halfway, 0.30 m
    assert lifts(0.29) and not lifts(0.31)
    p.lifts[3] = 3.4  # fully tucked: 0.4 s of contact
    assert lifts(0.19) and not lifts(0.21)
    assert p.lift_amplitude(0.27, 0) > 1.0 and p.lift_amplitude(0.29, 0) == 1.0  # a tucked context: 0.28 m
    off = ImprovedPremotor(4, 28, BASE, ImprovedConfig(tucked_contexts=2, lift_max=3.4, range_follows_tuck=False),
                           tuck=tuck)
    off.lifts[3] = 3.4
    assert off.lift_amplitude(0.39, 3) > 1.0  # off: 0.40 m whatever the tuck


def test_with_spread_at_lift_edge_the_credit_stops_at_the_contexts_lift_range():
    """A tucked context lifts within 0.28 m (cells 0-6 of 0.04 m): a gate on one side spreads its
    credit only to the cells on its own side; without the rule it reaches across."""
    def traces(edge: bool, cell: int) -> np.ndarray:
        config = ImprovedConfig(tucked_contexts=2, lift_max=3.44, context_share=0.5, spread_at_lift_edge=edge)
        p = ImprovedPremotor(4, 28, BASE, config, cell_width_m=0.04)
        p.on_step_onset(0.0, cell, context=1)
        return p.traces.at(0.0).reshape(4, 28)

    beyond = traces(True, 8)
    assert beyond[1, 7] > 0.0 and beyond[1, 12] > 0.0 and beyond[1, 3:7].sum() == 0.0
    assert beyond[0, 7] > 0.0 and beyond[0, 3:7].sum() == 0.0  # the shared row, alike
    within = traces(True, 5)
    assert within[1, 1] > 0.0 and within[1, 6] > 0.0 and within[1, 7:].sum() == 0.0
    assert traces(False, 8)[1, 4] > 0.0  # the rule off: across the edge as before
    with pytest.raises(ValueError, match="cell width"):
        ImprovedPremotor(4, 28, BASE, ImprovedConfig(spread_at_lift_edge=True), cell_width_m=None)


def test_with_too_close_at_lift_edge_rule_4_moves_only_the_gate_befores_side_of_the_lift_range():
    """A plain step from cell 7 (beyond the tucked range, 0.28 m) put the foot at the face; the
    empty gate after it fires rule 4 ("placement"). The spread's credit reaches the tucked cells
    below 0.28 m; with the rule they keep their weights."""
    def run(rule: bool) -> np.ndarray:
        config = ImprovedConfig(tucked_contexts=2, lift_max=3.44, context_share=0.5, too_close_at_lift_edge=rule)
        p = ImprovedPremotor(4, 28, BASE, config, cell_width_m=0.04)
        p.on_step_onset(0.0, 7, context=1)
        assert p.lift_amplitude(0.30, 1) == 1.0  # a plain step
        p.on_step_onset(0.7, None, context=1)
        p.on_contact_reflex(reflex("extension", 1.0, cause="shin", swing=True, phase=0.3))
        assert p.too_close == 1
        return p.weights

    off, on = run(False), run(True)
    assert off[1, 6] < 0.0 and off[1, 7] < 0.0  # across the edge, as before
    assert on[1, 7] == off[1, 7] and on[1, 10] == off[1, 10] and on[0, 8] == off[0, 8]  # its own side: the same
    assert not on[:, :7].any()  # the tucked side: untouched, in the shared row too


def test_with_too_close_last_step_the_gates_before_the_last_step_learn_the_reflexs_own_kind():
    """Round 11: the step before (cell 15) took the foot into the gap, the plain step from there
    (cell 7) put it at the face and the empty gate after it fires rule 4. The placement is the
    last step's; the step before learns the phase's "extension" (a longer step before: the
    take-off nearer). A reflex whose phase already says placement is learnt as before."""
    def run(rule: bool, kind: str = "extension") -> np.ndarray:
        p = premotor(too_close_last_step=rule)
        p.on_step_onset(0.0, 15, context=1)
        p.on_step_onset(0.7, 7, context=1)
        p.on_step_onset(1.4, None, context=1)
        p.on_contact_reflex(reflex(kind, 1.6, cause="shin", swing=True, phase=0.3))
        assert p.too_close == 1
        return p.weights

    off, on = run(False), run(True)
    assert off[1, 15] < 0.0 and off[1, 7] < 0.0  # every traced weight shorter, as before
    assert on[1, 7] == off[1, 7] and on[1, 12] == off[1, 12]  # the last step's neighbourhood: the same
    assert on[1, 15] == -off[1, 15] > 0.0 and on[0, 15] == -off[0, 15]  # the step before: longer
    assert (run(True, "placement") == run(False, "placement")).all()


def test_too_close_last_step_sets_each_cells_kind_before_the_branch_is_chosen():
    """With ``spread_keeps_branch`` a cell chooses its traces by the kind it learns. Under rule
    12 the step before learns "extension", so a cell there already on the longer branch takes
    the spread's credit (a cell on the other branch would take its own traces only: none)."""
    def run(rule: bool) -> np.ndarray:
        p = premotor(too_close_last_step=rule, spread_keeps_branch=True)
        p.weights[1, 17] = 0.05  # beyond the last step's reach (cells 2-12), within cell 15's spread
        p.weights[1, 4] = 0.05  # within the last step's reach: on the other branch than placement
        p.on_step_onset(0.0, 15, context=1)
        p.on_step_onset(0.7, 7, context=1)
        p.on_step_onset(1.4, None, context=1)
        p.on_contact_reflex(reflex("extension", 1.6, cause="shin", swing=True, phase=0.3))
        return p.weights

    on, off = run(True), run(False)
    assert on[1, 17] > 0.05  # longer, by the spread from cell 15
    assert off[1, 17] == 0.05  # all placement: on the other branch, no own trace, unchanged
    assert on[1, 4] == off[1, 4] == 0.05  # the last step's neighbourhood: placement, own traces only


def test_with_blend_readout_the_burst_reads_the_nearer_neighbour_by_the_gated_range():
    """Rule 13: cell 15 of 0.04 m spans 0.60-0.64 m; gated at 0.63 m the readout is 0.75 of cell
    15's weight and 0.25 of cell 16's (one branch); at 0.61 m, of cell 14's. Not across a branch
    (the signs differ, or a neighbour untrained), not across the lift's edge, not in the contexts
    that start tucked, and on by default."""
    def gated(blend: bool, range_m: float, w14: float, w16: float, cell: int = 15, w: float = 0.2,
              row: int = 2) -> float:
        config = ImprovedConfig(tucked_contexts=2, lift_max=3.44, blend_readout=blend)
        p = ImprovedPremotor(4, 28, BASE, config, cell_width_m=0.04)
        p.weights[row, cell] = w
        p.weights[row, cell - 1], p.weights[row, cell + 1] = w14, w16
        p.on_step_onset(0.0, cell, context=row)
        p.lift_amplitude(range_m, row)
        return p.gated_weight()

    assert gated(True, 0.63, 0.0, 0.4) == pytest.approx(0.75 * 0.2 + 0.25 * 0.4)
    assert gated(True, 0.61, 0.1, 0.4) == pytest.approx(0.75 * 0.2 + 0.25 * 0.1)
    assert gated(True, 0.62, 0.1, 0.4) == pytest.approx(0.2)  # at the centre: the cell alone
    assert gated(True, 0.63, 0.0, -0.4) == pytest.approx(0.2)  # the other branch: never between
    assert gated(True, 0.63, 0.0, 0.0) == pytest.approx(0.2)  # an untrained neighbour: no branch yet
    assert gated(False, 0.63, 0.0, 0.4) == pytest.approx(0.2)  # off: one-hot
    assert gated(True, 0.63, 0.0, 0.4, row=1) == pytest.approx(0.2)  # a context that starts tucked: one-hot
    # row 2 (a context that learns its lift) lifts within 0.40 m: cells 0-9; cell 9 and 10 straddle it
    assert gated(True, 0.399, 0.0, 0.4, cell=9) == pytest.approx(0.2)
    assert gated(True, 0.37, 0.4, 0.0, cell=9) == pytest.approx(0.75 * 0.2 + 0.25 * 0.4)
    assert ImprovedConfig().blend_readout  # a default since round 14
    with pytest.raises(ValueError, match="cell width"):
        ImprovedPremotor(4, 28, BASE, ImprovedConfig(blend_readout=True), cell_width_m=None)


def test_with_blend_tucked_rows_a_context_that_starts_tucked_reads_between_two_cells_too():
    """``blend_tucked_rows``: rule 13 in a context that starts tucked (row 1), within one branch
    and one side of its lift range's edge (0.28 m at 0.5 m/s: cells 0-6); off by default. (Rule 20
    off here: it would nudge cell 7, gated just beyond the edge.)"""
    def gated(on: bool, range_m: float, cell: int, w: float, w_below: float, w_above: float) -> float:
        config = ImprovedConfig(tucked_contexts=2, lift_max=3.44, blend_tucked_rows=on, near_edge_s=0.0)
        p = ImprovedPremotor(4, 28, BASE, config, cell_width_m=0.04)
        p.weights[1, cell] = w
        p.weights[1, cell - 1], p.weights[1, cell + 1] = w_below, w_above
        p.on_step_onset(0.0, cell, context=1)
        p.lift_amplitude(range_m, 1)
        return p.gated_weight()

    assert gated(True, 0.63, 15, -0.2, 0.0, -0.4) == pytest.approx(0.75 * -0.2 + 0.25 * -0.4)
    assert gated(False, 0.63, 15, -0.2, 0.0, -0.4) == pytest.approx(-0.2)
    assert gated(True, 0.63, 15, -0.2, 0.0, 0.4) == pytest.approx(-0.2)  # the other branch
    assert gated(True, 0.31, 7, -0.2, 0.0, -0.4) == pytest.approx(0.75 * -0.2 + 0.25 * -0.4)
    assert gated(True, 0.29, 7, -0.2, -0.4, 0.0) == pytest.approx(-0.2)  # cell 6 is across the edge
    assert gated(True, 0.25, 6, 0.2, 0.4, 0.0) == pytest.approx(0.75 * 0.2 + 0.25 * 0.4)
    assert not ImprovedConfig().blend_tucked_rows


def test_blended_steps_counts_the_step_cycles_whose_burst_the_blend_changed_once_each():
    """``blended_steps`` is how an experiment shows rule 13 never acted (its records then the
    one-hot readout's): a cycle counts once however often its burst is read, and only when the
    blend changed it."""
    p = ImprovedPremotor(4, 28, BASE, ImprovedConfig(tucked_contexts=2, lift_max=3.44), cell_width_m=0.04)
    p.weights[2, 15], p.weights[2, 16] = 0.2, 0.4

    def step(range_m: float, reads: int = 3) -> None:
        p.on_step_onset(0.0, 15, context=2)
        p.lift_amplitude(range_m, 2)
        for _ in range(reads):
            p.gated_weight()

    step(0.62)  # at the cell's centre: the cell alone
    assert p.blended_steps == 0
    step(0.63)
    assert p.blended_steps == 1  # three reads, one cycle
    step(0.63)
    assert p.blended_steps == 2
    p.weights[2, 16] = -0.4  # the other branch: one-hot
    step(0.63)
    assert p.blended_steps == 2


ROUND24_TIMES = (0.56, 0.56, 0.48, 0.40)
"""``tucked_time_s`` before round 25 (0.28 m at 0.5 m/s): the edge the tests of rounds 20-21 place their gates by."""


def _tucking(**config) -> ImprovedPremotor:
    """Contexts 0-1 start tucked, 2-3 learn their lift; the gait tucks above a lift of 3.0."""
    return ImprovedPremotor(4, 28, BASE, ImprovedConfig(tucked_contexts=2, lift_max=3.44, **config),
                            tuck=TUCK, tucked_extra_s=0.3,
                            cell_width_m=0.04)


def test_with_tucked_keeps_burst_a_tucked_swing_in_a_context_that_learns_its_lift_ignores_a_negative_weight():
    """Round 15: a tucked crossing shortened by its gate's negative weight comes down on top, and
    the shortening cannot help the take-off, which the step before sets. Only a tucked swing,
    only in the contexts that learn their lift, only a negative weight; on by default."""
    def burst(keep: bool, row: int = 3, lift: float = 3.44, w: float = -0.3, range_m: float = 0.1) -> float:
        p = _tucking(tucked_keeps_burst=keep, keeps_burst_tucked_rows=False, blend_readout=False)
        p.lifts[row] = lift
        p.weights[row, 2] = w
        p.on_step_onset(0.0, 2, context=row)
        p.lift_amplitude(range_m, row)
        return p.burst_s(0.0)

    full = BASE + 0.3  # the fully tucked swing's burst
    assert burst(False) == pytest.approx(full - 0.3)  # off: the weight shortens it, as before
    assert burst(True) == pytest.approx(full)
    assert burst(True, w=0.1) == pytest.approx(full + 0.1)  # a positive weight: as before
    assert burst(True, lift=3.22) == pytest.approx(BASE + 0.15)  # half tucked: at least its own burst
    assert burst(True, lift=2.8) == pytest.approx(BASE - 0.3)  # not tucked: as before
    assert burst(True, range_m=0.5) == pytest.approx(BASE - 0.3)  # beyond the lift range: a plain step
    assert burst(True, row=1) == burst(False, row=1)  # a context that starts tucked: as before (rule 24 off)
    assert ImprovedConfig().tucked_keeps_burst  # a default since round 15


def test_with_keeps_burst_tucked_rows_a_context_that_starts_tucked_keeps_its_crossings_burst_too():
    """Round 19: rule 14 also in the contexts that start tucked (their crossing's take-off is set
    by the step before as well); only with rule 14 on, only a tucked swing, only a negative weight."""
    def burst(rows: bool, keep: bool = True, w: float = -0.3, range_m: float = 0.1) -> float:
        p = _tucking(tucked_keeps_burst=keep, keeps_burst_tucked_rows=rows, blend_readout=False)
        p.weights[1, 2] = w
        p.on_step_onset(0.0, 2, context=1)
        p.lift_amplitude(range_m, 1)  # row 1 starts tucked: fully tucked within its range
        return p.burst_s(0.0)

    full = BASE + 0.3
    assert burst(False) == pytest.approx(full - 0.3)  # off: the weight shortens it, as before
    assert burst(True) == pytest.approx(full)
    assert burst(True, keep=False) == pytest.approx(full - 0.3)  # only with rule 14
    assert burst(True, w=0.1) == pytest.approx(full + 0.1)
    assert burst(True, range_m=0.5) == pytest.approx(BASE - 0.3)  # beyond its range: a plain step
    assert ImprovedConfig().keeps_burst_tucked_rows  # a default since round 25 (rule 24)


def test_with_longest_burst_s_the_learner_asks_the_cpg_for_a_longer_swing():
    """Rule 24 (round 25): ``longest_burst_s`` (0.7 s; 0: the CPG's own bound) is the longest burst
    the learner asks the loop to let the CPG give (a longer tucked crossing reaches farther); the
    two lowest contexts lift within 0.60 s of contact to match, their crossing keeps its full
    burst, and on a plant slower than believed their edge comes nearer by 0.5 s x the difference.
    Shorter than the base burst it is refused."""
    config = ImprovedConfig()
    assert config.longest_burst_s == 0.7 and config.tucked_time_s[:2] == (0.60, 0.60)
    assert config.keeps_burst_tucked_rows and config.tucked_mismatch_s == 0.5
    assert ImprovedPremotor(4, 28, BASE).longest_burst_s == 0.7
    assert ImprovedPremotor(4, 28, BASE, ImprovedConfig(longest_burst_s=0.0)).longest_burst_s is None
    p = _tucking(blend_readout=False)  # rule 14 in rows 0-1 too, by default
    p.weights[1, 6] = -0.3
    p.on_step_onset(0.0, 6, context=1)
    assert p.lift_amplitude(0.29, 1) == pytest.approx(3.44)  # within 0.30 m: the tucked crossing
    assert p.burst_s(0.0) == pytest.approx(BASE + 0.3)  # its full burst (tucked_extra_s 0.3 here)
    with pytest.raises(ValueError, match="longest_burst_s"):
        ImprovedPremotor(4, 28, BASE, ImprovedConfig(longest_burst_s=0.25))


def _own_lessons(kinds: list[str], row: int, **config) -> list[float]:
    """The change of cell 15's weight in context ``row`` by each lesson of ``kinds``, each gated
    alone (no spread, no sharing, no commit, no flip; learning rate 0.1 s)."""
    p = _tucking(spread_cells=0.0, context_share=0.0, commit_earlier_s=0.0, learning_rate_s=0.1, flip_at=2.0,
                 **config)
    changes = []
    for k, kind in enumerate(kinds):
        t = 100.0 * k  # each trace long gone before the next gate
        before = float(p.weights[row, 15])
        p.on_step_onset(t, 15, context=row)
        p.on_reflex(kind, t)  # its own trace 1 at once
        changes.append(float(p.weights[row, 15]) - before)
    return changes


def test_with_settle_lifting_a_trained_synapse_learns_less_only_in_the_contexts_that_learn_their_lift():
    """Round 15: a tall block's take-off window is a few centimetres, and a full lesson moves the
    step before's stride by many: there a synapse's step falls as it is trained,
    ``learning_rate_s / (1 + trained / settle_lifting)``; the rows that start tucked learn as before."""
    def lessons(settle: float, row: int) -> list[float]:
        return _own_lessons(["extension"] * 3, row, settle_lifting=settle)

    assert lessons(0.0, 3) == pytest.approx([0.1, 0.1, 0.1])  # off: every lesson the full rate
    assert lessons(1.0, 3) == pytest.approx([0.1, 0.1 / 2.0, 0.1 / 3.0])
    assert lessons(1.0, 1) == pytest.approx([0.1, 0.1, 0.1])  # a context that starts tucked: as before
    assert ImprovedConfig().settle_lifting == 1.0  # a default since round 15


def test_with_settle_recovers_lessons_that_agree_restore_the_rate_and_a_reversal_settles_it():
    """``settle_recovers``: in a context that learns its lift, a cell's own lesson that goes the
    way its last one went halves its training (the rate recovers toward the full one); a lesson
    the other way adds to it as rule 15 does; a neighbour's credit (a trace below
    ``settle_own_trace``) never counts as its own; off by default."""
    def lessons(recovers: bool, kinds: list[str], row: int = 3) -> list[float]:
        return _own_lessons(kinds, row, settle_lifting=1.0, settle_recovers=recovers)

    e, pl = "extension", "placement"
    assert lessons(False, [e, pl, pl, pl]) == pytest.approx([0.1, -0.1 / 2, -0.1 / 3, -0.1 / 4])
    # trained 1 (e), 2 (pl reverses), 1 (pl agrees: halved), 0.5 (agrees again)
    assert lessons(True, [e, pl, pl, pl]) == pytest.approx([0.1, -0.1 / 2, -0.1 / 3, -0.1 / 2])
    # e, e: trained 1 then halved to 0.5; pl reverses: 1.5; e reverses: 2.5
    assert lessons(True, [e, e, pl, e]) == pytest.approx([0.1, 0.1 / 2, -0.1 / 1.5, 0.1 / 2.5])
    assert lessons(True, [e, e, e], row=1) == pytest.approx([0.1, 0.1, 0.1])  # starts tucked: full rate
    assert not ImprovedConfig().settle_recovers

    # a neighbour's credit (trace below settle_own_trace) neither settles by agreeing nor sets its way
    p = _tucking(settle_lifting=1.0, settle_recovers=True, spread_cells=1.5, spread_fade=1000.0, context_share=0.0,
                 commit_earlier_s=0.0, learning_rate_s=0.1, flip_at=2.0)
    for k in range(2):
        p.on_step_onset(100.0 * k, 15, context=3)
        p.on_reflex("extension", 100.0 * k)
    assert p.last_way[3, 15] == 1.0 and p.last_way[3, 16] == 0.0
    assert p.trained[3, 15] == pytest.approx(0.5)  # 1, then halved
    assert p.trained[3, 16] > 1.5  # two neighbour's shares of about 0.8, added as rule 15 adds them


def test_with_fresh_beyond_edge_the_cells_a_tucking_lift_range_leaves_behind_start_again():
    """``fresh_beyond_edge``: in a context that learns its lift (row 3) the lift range starts at
    0.40 m (cells 0-9); fully tucked, rule 11 moves it to 0.20 m (cells 0-4), and cells 5-9,
    learnt for a lifted swing, start again (weight and training 0), once; cells on either side
    keep theirs. Not in a context that starts tucked, not when frozen; on by default (rule 23)."""
    def run(on: bool = True, row: int = 3, learning: bool = True) -> ImprovedPremotor:
        p = _tucking(fresh_beyond_edge=on, learning=learning)
        p.weights[row, :] = 0.4
        p.trained[row, :] = 3.0
        p.own_trained[row, :] = 3.0
        p.lifts[row] = 3.44  # fully tucked
        p.on_step_onset(0.0, 20, context=row)
        p.lift_amplitude(0.82, row)
        return p

    p = run()
    assert list(p.weights[3, 5:10]) == [0.0] * 5 and list(p.trained[3, 5:10]) == [0.0] * 5
    assert list(p.own_trained[3, 5:10]) == [0.0] * 5 and p.own_trained[3, 4] == 3.0
    assert p.weights[3, 4] == 0.4 and p.weights[3, 10] == 0.4 and p.trained[3, 4] == 3.0
    assert p.fresh_cells == 5
    p.weights[3, 5:10] = -0.1  # learnt again as plain steps: the same edge resets nothing
    p.on_step_onset(1.0, 20, context=3)
    p.lift_amplitude(0.82, 3)
    assert list(p.weights[3, 5:10]) == [-0.1] * 5 and p.fresh_cells == 5
    assert (run(on=False).weights[3] == 0.4).all()
    assert (run(learning=False).weights[3] == 0.4).all()
    assert (run(row=1).weights[1] == 0.4).all()  # starts tucked: its range never moves with its lift
    assert ImprovedConfig().fresh_beyond_edge  # a default since round 24


def test_a_contact_in_the_air_late_in_a_lifted_swing_raises_the_lift_by_default():
    """Round 15: a partly tucked swing whose foot strikes the block late in the swing (coming
    down on its near edge) was too low as well; with ``lift_phase`` 1.0, the default since, any
    contact in the air of a lifted swing raises that context's lift. At 0.5 (before) only the
    first half's did. A contact in stance or a landing on top never does."""
    def raised(phase: float, lift_phase: float | None = None, cause: str = "foot_in_air",
               swing: bool = True) -> bool:
        p = _tucking() if lift_phase is None else _tucking(lift_phase=lift_phase)
        p.on_step_onset(0.0, 3, context=3)
        assert p.lift_amplitude(0.13, 3) == pytest.approx(1.9)
        p.on_contact_reflex(reflex("extension", 0.5, cause=cause, swing=swing, phase=phase))
        return bool(p.lifts[3] > 1.9)

    assert raised(0.76)
    assert not raised(0.76, lift_phase=0.5) and raised(0.3, lift_phase=0.5)
    assert not raised(0.9, cause="foot_on_top") and not raised(0.7, cause="shin", swing=False)
    assert ImprovedConfig().lift_phase == 1.0


def test_by_default_three_contexts_start_tucked_and_the_tallest_learns_its_lift_sharing_with_none():
    """Round 16 (rule 17): the 0.09-0.13 m context starts tucked too. It starts at lift_max and
    lifts within its tucked_time_s (0.48 s: 0.24 m at 0.5 m/s); the tallest starts at the
    hardwired lift within 0.40 m, and with no other context of its kind it shares no credit."""
    config = ImprovedConfig()
    assert config.tucked_contexts == 3

    def default() -> ImprovedPremotor:
        return ImprovedPremotor(4, 28, BASE, config, tuck=TUCK, tucked_extra_s=0.3, cell_width_m=0.04)

    p = default()
    top = config.lift_max
    assert p.lifts.tolist() == [top, top, top, config.lift_amplitude]
    assert p.lift_amplitude(0.23, 2) == top and p.lift_amplitude(0.25, 2) == 1.0
    assert p.lift_amplitude(0.39, 3) == config.lift_amplitude and p.lift_amplitude(0.41, 3) == 1.0

    def traced_rows(row: int) -> list[bool]:
        q = default()
        q.on_step_onset(0.0, 10, context=row)
        return (q.traces.at(0.0).reshape(4, 28).sum(axis=1) > 0.0).tolist()

    assert traced_rows(2) == [True, True, True, False]  # shared with the two below, its kind
    assert traced_rows(3) == [False, False, False, True]  # its kind has no other context


def test_only_a_tucked_swing_in_a_context_that_learns_its_lift_descends_late():
    """Rule 18: ``lifting_descend_phase`` is told to the loop (tucked_descend_phase) for a tucked
    swing of the tallest context only; the contexts that start tucked, an untucked lift and a
    plain step keep the gait's descent (NaN)."""
    config = ImprovedConfig(lifting_descend_phase=0.84)
    p = ImprovedPremotor(4, 28, BASE, config, tuck=TUCK, tucked_extra_s=0.3, cell_width_m=0.04)
    p.on_step_onset(0.0, 5, context=0)
    assert p.lift_amplitude(0.2, 0) == config.lift_max and math.isnan(p.tucked_descend_phase())
    p.lifts[3] = 1.9  # not tucked: the hardwired lift's half-sine
    p.on_step_onset(1.0, 5, context=3)
    assert p.lift_amplitude(0.2, 3) == 1.9 and math.isnan(p.tucked_descend_phase())
    p.lifts[3] = config.lift_max  # tucked
    p.on_step_onset(2.0, 5, context=3)
    assert p.lift_amplitude(0.2, 3) == config.lift_max and p.tucked_descend_phase() == 0.84
    p.on_step_onset(3.0, 20, context=3)  # beyond the lift range: a plain step
    assert p.lift_amplitude(0.9, 3) == 1.0 and math.isnan(p.tucked_descend_phase())
    off = ImprovedPremotor(4, 28, BASE, ImprovedConfig(lifting_descend_phase=0.0), tuck=TUCK,
                           tucked_extra_s=0.3, cell_width_m=0.04)
    off.lifts[3] = config.lift_max
    off.on_step_onset(0.0, 5, context=3)
    off.lift_amplitude(0.2, 3)
    assert math.isnan(off.tucked_descend_phase())


def test_with_stance_follows_speed_the_stance_is_told_the_sensed_speed_beyond_the_deadband_only():
    """Round 19, rule 19: the belief within ``stance_speed_deadband_m_s`` of the sensed speed (the
    gait's own sweep, float for float), or before ``stance_speed_after`` closing speeds are fused;
    the sensed speed beyond it; NaN with the setting off."""
    def told(follow: bool, speeds: list[float], deadband: float = 0.02, after: int = 20) -> float:
        p = ImprovedPremotor(4, 28, BASE, ImprovedConfig(stance_follows_speed=follow, stance_speed_after=after,
                                                          stance_speed_deadband_m_s=deadband,
                                                          speed_belief_sd_m_s=0.05), ground_speed_m_s=0.5)
        for speed in speeds:
            p.observe_closing_speed(speed, 0.0001)
        return p.stance_speed_m_s()

    assert math.isnan(told(False, [0.45] * 20))
    assert told(True, []) == 0.5
    assert told(True, [0.49] * 20) == 0.5  # within the deadband: the belief
    slow = told(True, [0.45] * 20)
    assert 0.45 < slow < 0.455  # the fused speed, the belief's weight nearly gone
    assert told(True, [0.45] * 20, deadband=0.1) == 0.5
    assert told(True, [0.45] * 19) == 0.5  # one gate short of stance_speed_after (20)
    assert told(True, [0.45] * 5, after=5) == pytest.approx(slow, abs=0.005)


def _step_before_gate(p: ImprovedPremotor, row: int, cell: int, range_m: float, before_row: int | None = None,
                      before_m: float = 0.60) -> None:
    """The step before gated at cell 15 and ``before_m`` (default 0.60 m: beyond every lift range) at
    0 s in the context ``before_row`` (default ``row``), then a gate at ``cell`` and ``range_m`` at
    0.6 s in the context ``row``."""
    before_row = row if before_row is None else before_row
    p.on_step_onset(0.0, 15, context=before_row)
    p.lift_amplitude(before_m, before_row)
    p.on_step_onset(0.6, cell, context=row)
    p.lift_amplitude(range_m, row)


def _step_before_then(p: ImprovedPremotor, row: int, cell: int, range_m: float, r: Reflex) -> None:
    """:func:`_step_before_gate`, then the reflex ``r``."""
    _step_before_gate(p, row, cell, range_m)
    p.on_contact_reflex(r)


def test_with_plain_on_top_shortens_a_plain_step_on_top_learns_shorter_and_the_step_before_longer():
    """Round 20: in a context that starts tucked, a swing that did not lift and came down on top of
    the block was too long (a plain step cannot clear it; shorter, the next gate lifts), and the
    step before it too short. Only a foot on top, only a swing that did not lift, only in the
    contexts that start tucked; off by default."""
    def lesson(on: bool, row: int = 1, range_m: float = 0.30, cause: str = "foot_on_top") -> tuple[float, float]:
        p = _tucking(plain_on_top_shortens=on, spread_cells=0.0, context_share=0.0, commit_earlier_s=0.0,
                     flip_at=2.0, learning_rate_s=0.1, blend_readout=False, settle_lifting=0.0)
        _step_before_then(p, row, 7, range_m, reflex("extension", 1.0, cause=cause))
        return float(p.weights[row, 7]), float(p.weights[row, 15])

    plain, before = lesson(False)
    assert plain > 0.0 and before > 0.0  # off: the reflex's own kind for both, as before
    plain, before = lesson(True)
    assert plain < 0.0 and before > 0.0
    assert all(w > 0.0 for w in lesson(True, range_m=0.20))  # a lifted swing (row 1 lifts within 0.28 m)
    assert all(w > 0.0 for w in lesson(True, row=3, range_m=0.45))  # a context that learns its lift (beyond 0.40 m)
    assert all(w > 0.0 for w in lesson(True, cause="shin"))  # a shin contact is not a foot on top
    assert not ImprovedConfig().plain_on_top_shortens


def test_with_on_top_extends_before_a_crossing_on_top_teaches_a_short_step_before_longer():
    """Round 20: a tucked crossing (the longest swing) that came down on top took off beyond its
    window, so the step before was too short whichever branch rule 8 had committed it to: that
    lesson moves a weight committed to the short branch up; the long branch is committed as before.
    Only for a tucked crossing in a context that starts tucked; off by default."""
    def before(on: bool, w: float = -0.3, crossing_m: float = 0.20) -> float:
        p = _tucking(on_top_extends_before=on, spread_cells=0.0, context_share=0.0, commit_earlier_s=0.1,
                     flip_at=2.0, learning_rate_s=0.1, blend_readout=False)
        p.weights[1, 15] = w
        _step_before_then(p, 1, 5, crossing_m, reflex("extension", 1.0))  # within 0.28 m: fully tucked
        return float(p.weights[1, 15])

    assert before(False) < -0.3  # off: rule 8 moves it further along its own sign
    assert before(True) > -0.3
    assert before(False, w=0.3) > 0.3 and before(True, w=0.3) == before(False, w=0.3)
    assert before(True, crossing_m=0.35) == before(False, crossing_m=0.35)  # a plain step: as before
    assert not ImprovedConfig().on_top_extends_before


def test_with_edge_on_cell_a_context_that_starts_tucked_lifts_below_the_nearest_cell_boundary():
    """Round 20: the tucked range at the sensed speed falls inside a cell at another speed (0.252 m
    at 0.45 m/s), where one weight would drive both a plain step and a crossing; with the setting
    it moves to the nearest boundary. At the believed speed (0.28 m, a boundary) nothing changes."""
    def limit(on: bool, speed_m_s: float, row: int = 0) -> float:
        p = _tucking(edge_on_cell=on, tucked_time_s=ROUND24_TIMES, tucked_mismatch_s=0.0)
        p.ground_speed_m_s = speed_m_s  # as rule 10's fused closing speeds would set it
        return p._lift_limit_m(row)

    assert limit(True, 0.5) == limit(False, 0.5) == pytest.approx(0.28)
    assert limit(False, 0.45) == pytest.approx(0.252)
    assert limit(True, 0.45) == pytest.approx(0.24)
    assert limit(True, 0.55) == pytest.approx(0.32)
    assert limit(True, 0.45, row=3) == limit(False, 0.45, row=3)  # a context that learns its lift: as before
    assert not ImprovedConfig().edge_on_cell
    with pytest.raises(ValueError, match="edge_on_cell"):
        ImprovedPremotor(4, 28, BASE, ImprovedConfig(edge_on_cell=True, blend_readout=False), cell_width_m=None)


def test_with_commit_to_bound_a_committed_weight_moves_its_traces_fraction_of_the_way_to_its_bound():
    """Round 20: rule 8 moves a committed weight along its own sign by the learning rate; with the
    setting, toward its branch's extreme (the bound) by its trace's fraction of the way. A weight
    not committed learns as before."""
    def after(on: bool, w: float, kind: str = "placement") -> float:
        p = _tucking(commit_to_bound=on, spread_cells=0.0, context_share=0.0, commit_earlier_s=0.1,
                     flip_at=2.0, learning_rate_s=0.1, blend_readout=False, weight_limit_s=0.5)
        p.weights[1, 15] = w
        _step_before_then(p, 1, 5, 0.20, reflex(kind, 1.0))
        return float(p.weights[1, 15])

    trace = math.exp(-1.0 / 4.0)  # the step before's, 1 s after its gate (trace_tau_s 4 s)
    assert after(False, 0.25) == pytest.approx(0.25 + 0.1 * trace)
    assert after(True, 0.25) == pytest.approx(0.25 + 0.25 * trace)
    assert after(True, -0.25, kind="extension") == pytest.approx(-0.25 - 0.25 * trace)
    assert after(True, 0.05) == after(False, 0.05) == pytest.approx(0.05 - 0.1 * trace)  # not committed
    assert not ImprovedConfig().commit_to_bound


def test_with_tucked_mismatch_s_a_tucked_context_lifts_nearer_on_a_plant_slower_than_believed():
    """Round 20: a fully tucked swing lasts as long at any speed, so on a plant slower than the
    controller believes it covers less ground, and its take-off window's far edge comes nearer
    than the time to contact at the sensed speed puts it. With the setting the tucked range moves
    by ``tucked_mismatch_s`` x (believed - sensed), once the sensed speed is to be believed (the
    wait and the deadband of ``stance_follows_speed``); within them, or off, it is as before."""
    def limit(mismatch_s: float, speed_m_s: float, samples: int = 20, row: int = 0) -> float:
        p = _tucking(tucked_mismatch_s=mismatch_s, tucked_time_s=ROUND24_TIMES)
        p.ground_speed_m_s, p.speed_samples = speed_m_s, samples  # as rule 10's fused closing speeds would
        return p._lift_limit_m(row)

    assert limit(0.0, 0.45) == pytest.approx(0.252)  # rule 9 at the sensed speed
    assert limit(0.6, 0.45) == pytest.approx(0.252 - 0.6 * 0.05)
    assert limit(0.6, 0.55) == pytest.approx(0.308 + 0.6 * 0.05)
    assert limit(0.6, 0.45, samples=19) == limit(0.0, 0.45)  # before the wait
    assert limit(0.6, 0.49) == limit(0.0, 0.49)  # within the deadband (0.02 m/s)
    assert limit(0.6, 0.45, row=3) == limit(0.0, 0.45, row=3)  # a context that learns its lift
    assert ImprovedConfig().tucked_mismatch_s == 0.5  # a default since round 25 (rule 24)


def test_with_near_edge_s_a_crossing_near_its_edge_moves_the_plain_step_before_away_from_the_gap():
    """Round 21: a tucked crossing gated within ``near_edge_m`` of its lift range's edge (0.28 m in
    a context that starts tucked) took off near its window's far edge: before any reflex, the plain
    step before it moves ``near_edge_s`` along its committed branch (extension if uncommitted).
    Not for a crossing deeper in the range, a gate beyond it (a plain step), a lifted step before,
    or a context that learns its lift; off by default."""
    def before(near_s: float, w: float = 0.0, range_m: float = 0.26, row: int = 1,
               before_m: float = 0.60, before_row: int | None = None) -> float:
        p = _tucking(near_edge_s=near_s, near_edge_m=0.04, commit_earlier_s=0.1)
        p.lifts[3] = 3.44  # row 3 learnt a tucked lift: its crossings are tucked too, within 0.20 m
        before_row = row if before_row is None else before_row
        p.weights[before_row, 15] = w
        _step_before_gate(p, row, int(range_m / 0.04), range_m, before_row, before_m)
        return float(p.weights[before_row, 15])

    assert before(0.0) == 0.0  # off: no reflex, no change
    assert before(0.05) == pytest.approx(0.05)  # uncommitted: extension, the crossing deeper
    assert before(0.05, w=0.3) == pytest.approx(0.35)  # the long branch: longer
    assert before(0.05, w=-0.3) == pytest.approx(-0.35)  # the short branch: shorter (the next gate plain)
    assert before(0.05, w=-0.05) == pytest.approx(0.0)  # not committed (below commit_earlier_s)
    assert before(0.05, w=0.48) == pytest.approx(0.5)  # within the bound
    assert before(0.05, range_m=0.20) == 0.0  # deeper than near_edge_m within the range
    assert before(0.05, range_m=0.30) == 0.0  # beyond the range: a plain step, no crossing
    assert before(0.05, before_m=0.27) == 0.0  # the step before lifted itself
    assert before(0.05, row=3, range_m=0.18, before_row=1) == 0.0  # a crossing of a context that learns its lift
    assert before(0.05, before_row=3) == 0.0  # the step before was gated in a context that learns its lift
    assert ImprovedConfig().near_edge_s == 0.05  # a default since round 23


def test_with_near_edge_plain_a_plain_step_just_beyond_the_edge_learns_shorter_as_it_is_gated():
    """Round 21: a plain step gated within ``near_edge_m`` beyond the lift range's edge (0.28 m in a
    context that starts tucked) is the last before the crossing; a long one leaves the crossing at
    the face. With the setting its own weight moves ``near_edge_s`` shorter at the gate, so this
    step's burst is already shorter. Not farther out, not a crossing, not in a context that learns
    its lift; off by default, and nothing without ``near_edge_s``."""
    def plain(on: bool, range_m: float = 0.30, row: int = 1, near_s: float = 0.05, w: float = 0.1) -> float:
        p = _tucking(near_edge_s=near_s, near_edge_plain=on, near_edge_m=0.04, tucked_time_s=ROUND24_TIMES)
        cell = int(range_m / 0.04)
        p.weights[row, cell] = w
        p.on_step_onset(0.0, cell, context=row)
        p.lift_amplitude(range_m, row)
        if range_m >= 0.28:  # a plain step (a crossing's burst is longer by tucked_extra_s)
            assert p.burst_s(0.0) == pytest.approx(BASE + float(p.weights[row, cell]))  # this step's burst
        return float(p.weights[row, cell])

    assert plain(False) == pytest.approx(0.1)
    assert plain(True) == pytest.approx(0.05)
    assert plain(True, w=-0.48) == pytest.approx(-0.5)  # within the bound
    assert plain(True, range_m=0.33) == pytest.approx(0.1)  # farther than near_edge_m beyond the edge
    assert plain(True, range_m=0.26) == pytest.approx(0.1)  # within the range: a crossing
    assert plain(True, row=3, range_m=0.42) == pytest.approx(0.1)  # a context that learns its lift (0.40 m)
    assert plain(True, near_s=0.0) == pytest.approx(0.1)
    assert ImprovedConfig().near_edge_plain  # a default since round 23


def test_with_near_edge_lifting_rule_20_acts_in_a_context_that_learns_its_lift_once_it_is_tucked():
    """Round 22: in a context that learns its lift (rows 2-3 here), once its lift is tucked (3.44:
    its edge 0.20 m, rule 11), a plain step gated just beyond the edge learns shorter, and a
    crossing gated just within it moves the plain step before it, of such a context, away from the
    gap. Not below the tuck (lift 1.9: the edge 0.40 m, a lifted swing), not from a context of the
    other kind or one not tucked; off by default."""
    def premotor(on: bool, lift: float) -> ImprovedPremotor:
        p = _tucking(near_edge_s=0.05, near_edge_plain=True, near_edge_lifting=on, near_edge_m=0.04,
                     commit_earlier_s=0.1, blend_readout=False)
        p.lifts[3] = lift
        return p

    def plain(on: bool, lift: float = 3.44) -> float:
        p = premotor(on, lift)
        p.on_step_onset(0.0, 5, context=3)  # 0.21 m: beyond the tucked edge, within 0.04 m of it
        p.lift_amplitude(0.21, 3)
        return float(p.weights[3, 5])

    def before(on: bool, before_row: int = 3, lift: float = 3.44) -> float:
        p = premotor(on, lift)
        p.weights[before_row, 15] = 0.3  # committed to the long branch
        _step_before_gate(p, 3, 4, 0.18, before_row)  # a tucked crossing at 0.18 m, within 0.04 m of 0.20 m
        return float(p.weights[before_row, 15])

    assert plain(False) == 0.0
    assert plain(True) == pytest.approx(-0.05)
    assert plain(True, lift=1.9) == 0.0  # below the tuck: 0.21 m is a lifted swing's
    assert before(False) == pytest.approx(0.3)
    assert before(True) == pytest.approx(0.35)
    assert before(True, before_row=1) == pytest.approx(0.3)  # a context that starts tucked: the other kind
    assert before(True, before_row=2) == pytest.approx(0.3)  # a context whose lift is not tucked (1.9)
    assert before(True, lift=1.9) == pytest.approx(0.3)  # 0.18 m is then a lifted swing's, no crossing's edge
    assert ImprovedConfig().near_edge_lifting  # a default since round 23


def test_with_near_close_m_a_tucked_crossing_gated_too_near_shortens_the_plain_step_before():
    """Round 23: in a context that learns its lift (rows 2-3 here), once its lift is tucked (3.44),
    a tucked crossing gated nearer than ``near_close_m`` took off at its window's near edge: the
    plain step before it, of such a context, moves ``near_edge_s`` shorter whatever its sign. Not
    for a crossing gated farther, below the tuck, in a context that starts tucked, after a step
    before of the other kind, or without ``near_edge_s``; on by default
    since round 23."""
    def before(close_m: float, range_m: float = 0.08, row: int = 3, before_row: int = 3, lift: float = 3.44,
               w: float = 0.3, near_s: float = 0.05) -> float:
        p = _tucking(near_edge_s=near_s, near_edge_plain=False, near_edge_lifting=True, near_close_m=close_m,
                     commit_earlier_s=0.1, blend_readout=False)
        p.lifts[3] = lift
        p.lifts[2] = lift
        p.weights[before_row, 15] = w
        _step_before_gate(p, row, int(range_m / 0.04), range_m, before_row)
        return float(p.weights[before_row, 15])

    assert before(0.0) == pytest.approx(0.3)  # off
    assert before(0.10) == pytest.approx(0.25)  # 0.08 m: nearer than 0.10 m, the long step before shorter
    assert before(0.10, w=-0.3) == pytest.approx(-0.35)  # a short one shorter still
    assert before(0.10, w=0.0) == pytest.approx(-0.05)
    assert before(0.10, w=-0.48) == pytest.approx(-0.5)  # within the bound
    assert before(0.10, range_m=0.12) == pytest.approx(0.3)  # gated farther: no near miss
    assert before(0.10, range_m=0.10) == pytest.approx(0.3)  # at near_close_m: not nearer
    assert before(0.10, near_s=0.0) == pytest.approx(0.3)  # the step is near_edge_s
    assert before(0.10, lift=1.9) == pytest.approx(0.3)  # below the tuck: a lifted swing, no tucked crossing
    assert before(0.10, row=1, before_row=1) == pytest.approx(0.3)  # a context that starts tucked
    assert before(0.10, before_row=1) == pytest.approx(0.3)  # the step before of the other kind
    assert before(0.10, before_row=2) == pytest.approx(0.25)  # the same kind, tucked: another row of it
    assert ImprovedConfig().near_close_m == 0.10  # a default since round 23


def test_with_plain_swing_shortens_a_plain_step_reaching_a_tall_block_learns_shorter():
    """Round 23: in a context that learns its lift, once that lift is tucked (3.44: its edge 0.20 m),
    a step gated beyond the edge did not lift; a contact in the air in its own swing means it
    reached the block, which a plain step cannot clear: its gate learns placement, the step before
    extension (so the next gate lifts). Only a contact in the air of such a swing, only in such a
    context once tucked; on by default since round 23."""
    def lesson(on: bool, row: int = 3, range_m: float = 0.22, lift: float = 3.44, cause: str = "shin",
               swing: bool = True) -> tuple[float, float]:
        p = _tucking(plain_swing_shortens=on, spread_cells=0.0, context_share=0.0, commit_earlier_s=0.0,
                     flip_at=2.0, learning_rate_s=0.1, blend_readout=False, settle_lifting=0.0,
                     near_edge_s=0.0)
        p.lifts[3] = lift
        cell = int(range_m / 0.04)
        _step_before_then(p, row, cell, range_m, reflex("extension", 1.0, cause=cause, swing=swing, phase=0.6))
        return float(p.weights[row, cell]), float(p.weights[row, 15])

    plain, before = lesson(False)
    assert plain > 0.0 and before > 0.0  # off: the reflex's own kind for both
    plain, before = lesson(True)
    assert plain < 0.0 and before > 0.0
    plain, before = lesson(True, cause="foot_in_air")
    assert plain < 0.0 and before > 0.0
    assert all(w > 0.0 for w in lesson(True, range_m=0.18))  # within the edge: a tucked crossing
    assert all(w > 0.0 for w in lesson(True, lift=1.9, range_m=0.45))  # the lift not tucked (edge 0.40 m)
    assert all(w > 0.0 for w in lesson(True, row=1, range_m=0.30))  # a context that starts tucked
    assert all(w > 0.0 for w in lesson(True, cause="foot_on_top"))  # not a contact in the air
    assert all(w > 0.0 for w in lesson(True, swing=False))  # in stance
    assert ImprovedConfig().plain_swing_shortens  # a default since round 23
