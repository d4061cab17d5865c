"""Restart after a data break with the plant's free response fitted (core/estimation/free_response_restart.py).

The [RA-SRIVC] §5 plant (three modes, decay times 0.5-8 s) at 20 Hz in the PID loop; the estimator starts at the
truth. Noise-free ZOH-exact data make the model exact, so a correct restart leaves the estimate exactly there.
"""
import numpy as np
import pytest

from additive_rsrivc_ros.core.estimation import kernel as kn
from additive_rsrivc_ros.core.estimation.free_response_restart import FreeResponseRestart, settle_length
from additive_rsrivc_ros.core.estimation.recursive import RecursiveAdditiveSRIVC
from additive_rsrivc_ros.core.estimation.recursive_state import hold_length
from additive_rsrivc_ros.core.model import SubmodelStructure
from additive_rsrivc_ros.sim.independent import PAPER_THETA, PID, paper_reference, simulate_modal

RATE = 20.0
TRUTH = np.array([np.asarray(t, dtype=float) for t in PAPER_THETA])
BREAK, GAP = 6000, 300          # the break after 300 s, 15 s of missing samples


def _loop(n, delay=1, noise_std=0.0, theta=None, seed=3):
    t = np.arange(n) / RATE
    r = paper_reference(t)
    u, y = simulate_modal([*TRUTH] if theta is None else theta, RATE, n, r=r, controller=PID, delay=delay,
                          noise_std=noise_std, seed=seed)
    return r, u, y


def _est(delay=1, **kw):
    return RecursiveAdditiveSRIVC([SubmodelStructure()] * 3, [*TRUTH], RATE, forgetting=0.999, controller=PID,
                                  input_delay=delay, **kw)


def _after_break(est, r, u, y):
    """Run to the break, mark the gap, run on; theta after every sample from the resumption on."""
    est.update(r[:BREAK], u[:BREAK], y[:BREAK])
    est.mark_gap()
    a = BREAK + GAP
    return est.update(r[a:], u[a:], y[a:], trace=True)


@pytest.mark.parametrize("delay", [0, 1, 3])
def test_a_restart_with_the_fitted_free_response_is_exact_when_the_model_is(delay):
    """The fit takes a few periods instead of five decay times, and leaves the estimate at the truth (round-off);
    controls: the same short hold without the fit moves it by percents, the full hold leaves the decayed rest."""
    r, u, y = _loop(16000, delay)
    n_settle = settle_length(TRUTH, np.zeros(3, np.int64), RATE, delay)
    n_hold = hold_length(TRUTH, np.zeros(3, np.int64), RATE, None)
    assert n_settle < n_hold / 3                      # 3 slowest periods (10 s) against 5 decay times (40 s)
    fitted = _est(delay)
    tr = _after_break(fitted, r, u, y)
    assert fitted.health.held_samples == n_settle and fitted.health.hold_remaining == 0
    assert np.max(np.abs(tr / TRUTH - 1.0)) < 1e-9
    assert fitted.residual_variance < 1e-20
    short = _est(delay, fit_free_response=False, reprime_s=n_settle / RATE)
    assert np.max(np.abs(_after_break(short, r, u, y) / TRUTH - 1.0)) > 0.01
    full = _est(delay, fit_free_response=False)
    tr_full = _after_break(full, r, u, y)
    assert full.health.held_samples == n_hold
    assert 1e-5 < np.max(np.abs(tr_full / TRUTH - 1.0)) < 0.01


def test_a_change_during_the_break_is_tracked_sooner():
    """Mode 2's frequency drops 3 % during the break: the estimate gets half-way at least half the saved hold
    earlier than with the full hold, and both reach the new frequency."""
    n = 20000
    traj = np.repeat(TRUTH[None], n, axis=0)
    traj[BREAK + GAP // 2:, 1, 1] = TRUTH[1, 1] / 0.97 ** 2
    r, u, y = _loop(n, noise_std=0.05, theta=traj, seed=4)

    def half_way(est):
        f_rel = np.sqrt(TRUTH[1, 1] / _after_break(est, r, u, y)[:, 1, 1]) - 1.0
        assert f_rel[-1] == pytest.approx(-0.03, abs=0.003)
        return int(np.argmax(f_rel < -0.015))

    saved = hold_length(TRUTH, np.zeros(3, np.int64), RATE, None) - settle_length(TRUTH, np.zeros(3, np.int64), RATE, 1)
    assert half_way(_est(fit_free_response=False)) - half_way(_est()) > saved / 2


def test_a_plant_that_changed_much_during_the_break_keeps_collecting():
    """Mode 2's frequency drops 10 % (four half-power bandwidths) during the break: the old model's free response
    explains too little of the output error, so the collection is doubled until it does or the full hold ends;
    the estimate moves most of the way to the new frequency (690 s of data, memory 50 s)."""
    n = 20000
    traj = np.repeat(TRUTH[None], n, axis=0)
    traj[BREAK + GAP // 2:, 1, 1] = TRUTH[1, 1] / 0.9 ** 2
    r, u, y = _loop(n, noise_std=0.05, theta=traj, seed=4)
    est = _est()
    f_rel = np.sqrt(TRUTH[1, 1] / _after_break(est, r, u, y)[:, 1, 1]) - 1.0
    assert est.health.held_samples > settle_length(TRUTH, np.zeros(3, np.int64), RATE, 1)
    assert -0.11 < f_rel[-1] < -0.07


def test_a_plant_changed_during_the_break_shows_on_the_residual_level_from_the_first_misfit(tmp_path):
    """While the collection's output error is the free response being fitted, health's residual level stays at its
    level before the break; once a fit leaves more than the noise (mode 2 10 % lower), that error is an anomaly
    and shows at once, not only when the full hold ends; a snapshot taken then keeps that."""
    n_settle = settle_length(TRUTH, np.zeros(3, np.int64), RATE, 1)
    a = BREAK + GAP
    stop = a + n_settle + n_settle // 2              # the first fit at n_settle; a doubled collection lasts

    def after_first_fit(theta, path=None):
        r, u, y = _loop(stop + 3 * n_settle, noise_std=0.05, theta=theta, seed=4)
        est = _est()
        est.update(r[:BREAK], u[:BREAK], y[:BREAK])
        level = est.residual_variance
        est.mark_gap()
        est.update(r[a:stop], u[a:stop], y[a:stop])
        if path is not None:
            est.save(path)
            est.update(r[stop:], u[stop:], y[stop:])
            back = RecursiveAdditiveSRIVC.restore(path)
            back.update(r[stop:], u[stop:], y[stop:])
            assert back.residual_variance == est.residual_variance
            assert back.health.held_samples == est.health.held_samples
        return est, level

    same, level = after_first_fit(None)
    assert same.health.hold_remaining == 0 and same.residual_variance < 2.0 * level       # fitted, resumed
    traj = np.repeat(TRUTH[None], stop + 3 * n_settle, axis=0)
    traj[BREAK + GAP // 2:, 1, 1] = TRUTH[1, 1] / 0.9 ** 2
    changed, level = after_first_fit(traj)
    assert changed.health.hold_remaining > 0 and changed.residual_variance > 2.0 * level  # still collecting
    after_first_fit(traj, tmp_path / "state.npz")


@pytest.mark.parametrize("collected", [0, 1, 7])
def test_a_collection_saved_with_or_without_the_misfit_flag_reads_back(collected):
    """The saved collection: n_target, residual level, last input, misfit flag, then four rows of samples; a layout
    without the flag (saved before it existed) reads as no misfit seen, with its samples intact."""
    samples = np.arange(4.0 * collected).reshape(4, collected)
    saved = FreeResponseRestart(20, 0.5, 2.0, -1.0, samples, misfit=True)
    back = FreeResponseRestart.from_array(saved.to_array())
    assert back is not None and back.misfit and back.n_target == 20 and (back.sig_acc, back.sig_w) == (0.5, 2.0)
    assert np.array_equal(back.samples, samples)
    older = np.concatenate(([20, 0.5, 2.0, -1.0], samples.ravel()))
    back = FreeResponseRestart.from_array(older)
    assert back is not None and not back.misfit and back.u_last == -1.0 and np.array_equal(back.samples, samples)


def test_skipped_samples_in_the_collection_leave_the_fit_exact():
    """Non-finite outputs and samples marked invalid after the break are left out of the fit, not fitted."""
    r, u, y = _loop(16000)
    y = y.copy()
    valid = np.ones(y.size, bool)
    y[BREAK + GAP + 40:BREAK + GAP + 45] = np.nan
    valid[BREAK + GAP + 60] = False
    est = _est()
    est.update(r[:BREAK], u[:BREAK], y[:BREAK])
    est.mark_gap()
    a = BREAK + GAP
    tr = est.update(r[a:], u[a:], y[a:], valid[a:], trace=True)
    assert est.health.held_samples < 250 and np.max(np.abs(tr / TRUTH - 1.0)) < 1e-9


def test_a_snapshot_taken_during_the_collection_continues_bit_identical(tmp_path):
    """Restored mid-collection and fed in other blocks (or sample by sample), the run is the same."""
    r, u, y = _loop(9000, delay=2, noise_std=0.1)
    ref = _est(2)
    ref.update(r[:BREAK], u[:BREAK], y[:BREAK])
    ref.mark_gap()
    a = BREAK + GAP
    mid = a + 100                                    # half of the 10 s collection
    ref.update(r[a:mid], u[a:mid], y[a:mid])
    ref.save(tmp_path / "state.npz")
    ref.update(r[mid:], u[mid:], y[mid:])
    b = RecursiveAdditiveSRIVC.restore(tmp_path / "state.npz")
    for k in range(mid, r.size, 77):                 # arbitrary blocks across the end of the collection
        b.update(r[k:k + 77], u[k:k + 77], y[k:k + 77])
    c = RecursiveAdditiveSRIVC.restore(tmp_path / "state.npz")
    for k in range(mid, mid + 150):                  # sample by sample to past the end of the collection
        c.update(r[k:k + 1], u[k:k + 1], y[k:k + 1])
    c.update(r[mid + 150:], u[mid + 150:], y[mid + 150:])
    sa = ref.get_state()
    assert ref.health.held_samples == b.health.held_samples == c.health.held_samples < 250
    for other in (b.get_state(), c.get_state()):
        for key in sa:
            assert np.array_equal(sa[key], other[key]), key


def test_the_full_hold_runs_where_the_fit_cannot_separate_the_modes():
    """A rigid body (its free response is in the recursion) or two modes at one frequency: no shortened hold."""
    kind = np.zeros(3, np.int64)
    assert settle_length(TRUTH, np.array([0, 0, 1]), RATE, 0) == 0
    twins = TRUTH.copy()
    twins[2] = twins[1]
    assert settle_length(twins, kind, RATE, 0) == 0
    r, u, y = _loop(9000)
    est = RecursiveAdditiveSRIVC([SubmodelStructure()] * 3, [*twins], RATE, forgetting=0.999, controller=PID,
                                 input_delay=1)
    est.update(r[:BREAK], u[:BREAK], y[:BREAK])
    est.mark_gap()
    est.update(r[BREAK + GAP:], u[BREAK + GAP:], y[BREAK + GAP:])
    assert est.health.held_samples == hold_length(twins, kind, RATE, None)


def test_a_fit_that_does_not_match_the_filters_keeps_the_full_hold():
    """The filters moved during the collection (a new filter model): the fit is dropped, the hold runs on."""
    r, u, y = _loop(9000)
    est = _est()
    est.update(r[:BREAK], u[:BREAK], y[:BREAK])
    est.mark_gap()
    a = BREAK + GAP
    est.update(r[a:a + 50], u[a:a + 50], y[a:a + 50])
    est._s["phi"][1] *= 1.0 + 1e-3
    est.update(r[a + 50:], u[a + 50:], y[a + 50:])
    assert est.health.held_samples == hold_length(TRUTH, np.zeros(3, np.int64), RATE, None)
    assert np.all(np.isfinite(est.get_state()["xs"][:, kn.BU]))
