"""The bounded redraw driver (clrender.estimators.redraw.estimate_with_redraw)."""

import numpy as np
import pytest

from clrender.errors import ClrenderError, ParameterError
from clrender.estimators.redraw import estimate_with_redraw
from clrender.samples import SampleSets
from clrender.sppp import draw_sppp, sppp_eps

N = 256


def holder_1(samples: SampleSets) -> np.ndarray:
    return np.abs(samples.traced[:, 0] * samples.traced[:, 1])


def with_holder_1(draw_sets):
    """The driver's draw(pixel_ids, eps): the sample sets of draw_sets and their holder_1 values."""

    def draw(pixel_ids, eps):
        samples = draw_sets(pixel_ids, eps)
        return samples, holder_1(samples)

    return draw


def sppp_drawer(seed: int):
    rng = np.random.default_rng(seed)
    return with_holder_1(lambda pixel_ids, eps: draw_sppp(rng, N, len(pixel_ids), eps=eps))


def test_tiny_eps_terminates_counts_and_enlarges_eps():
    # eps = 0.01 is far below sppp_eps(256) = 0.144: nearly every pixel is rejected until eps
    # has been enlarged: the first enlargement (after 3 redraws) jumps to the paper's eps at
    # least, each later one multiplies it by 1.5.
    outcome = estimate_with_redraw(
        ["vor", "vor_sn", "fvor"], sppp_drawer(31), pixels=40, n=N, eps=0.01
    )
    stats = outcome.stats
    assert stats.redraws > 40
    assert stats.eps_enlargements >= 1
    assert stats.final_eps == pytest.approx(sppp_eps(N) * 1.5 ** (stats.eps_enlargements - 1))
    assert stats.rounds == len(stats.redraws_per_round) + 1
    assert sum(stats.redraws_per_round) == stats.redraws
    for values in outcome.estimates.values():
        assert values.shape == (40,) and np.isfinite(values).all()


def test_default_eps_rarely_redraws():
    outcome = estimate_with_redraw("vor", sppp_drawer(32), pixels=100, n=N)
    assert outcome.stats.rounds <= 2 and outcome.stats.eps_enlargements == 0
    assert np.isfinite(outcome.estimates["vor"]).all()


def test_zero_eps_is_enlarged_to_a_positive_width():
    outcome = estimate_with_redraw(
        "vor", sppp_drawer(33), pixels=10, n=N, eps=0.0, redraws_before_enlarge=0
    )
    assert outcome.stats.final_eps > 0 and np.isfinite(outcome.estimates["vor"]).all()


def sets_without_aux(pixel_ids, eps):
    """A sampler that ignores eps and never draws auxiliary nuclei."""
    batch = draw_sppp(np.random.default_rng(34), N, len(pixel_ids), eps=0.0)
    return SampleSets(
        batch.traced,
        batch.offsets,
        N,
        np.zeros((0, 2)),
        np.zeros(len(pixel_ids) + 1, np.int64),
        eps,
    )


without_aux = with_holder_1(sets_without_aux)


def test_hard_cap_raises_a_clear_error():
    with pytest.raises(ClrenderError, match="unbounded Voronoi cell after 5 draws"):
        estimate_with_redraw("vor", without_aux, pixels=3, n=N, max_rounds=5)


def test_hard_cap_can_fall_back_to_mc():
    outcome = estimate_with_redraw(
        ["vor", "fvor"], without_aux, pixels=3, n=N, max_rounds=4, on_exhausted="mc"
    )
    assert outcome.stats.exhausted_pixels == 3
    batch = sets_without_aux(np.arange(3), 0.0)  # the same seed: the last draw's samples
    mc = np.bincount(np.repeat(np.arange(3), np.diff(batch.offsets)), holder_1(batch), 3) / N
    np.testing.assert_allclose(outcome.estimates["vor"], mc)
    np.testing.assert_allclose(outcome.estimates["fvor"], mc)


def test_estimators_that_never_reject_finish_in_one_round():
    outcome = estimate_with_redraw(["mc", "cvor", "pvor"], without_aux, pixels=5, n=N)
    assert outcome.stats.rounds == 1 and outcome.stats.redraws == 0


@pytest.mark.parametrize(
    "kwargs", [{"enlarge_factor": 1.0}, {"max_rounds": 0}, {"on_exhausted": "ignore"}]
)
def test_bad_driver_parameters(kwargs):
    with pytest.raises(ParameterError):
        estimate_with_redraw("vor", sppp_drawer(35), pixels=1, n=N, **kwargs)


def test_unknown_estimator_name_fails_before_drawing():
    def must_not_draw(pixel_ids, eps):
        raise AssertionError("drew samples for an unknown estimator")

    with pytest.raises(ParameterError, match="accepted"):
        estimate_with_redraw("nope", must_not_draw, pixels=1, n=N)
