"""studies.ladder_over_seeds: a ladder step is called a rise only when the seeds cannot explain it."""
import numpy as np
import pytest

from studies.ladder_over_seeds import RISE_LIMIT, markdown, step_figures


def test_a_steady_rise_beyond_the_limit_is_flagged():
    previous = np.array([0.50, 0.60, 0.70, 0.55, 0.65, 0.58])
    current = previous * 1.3 + 0.01   # every seed 30% worse: the paired differences hardly scatter
    step = step_figures(previous, current)
    assert step["ratio"] == pytest.approx(1.0 + (current - previous).mean() / previous.mean())
    assert step["low"] > RISE_LIMIT and step["rise"]


def test_a_rise_the_seeds_explain_is_not_flagged():
    # sponza's seed-0 step 0.61 -> 0.85 in val_clustered's ladder, with the other seeds falling
    previous = np.array([0.61, 0.65, 0.90, 0.65, 0.76, 0.69])
    current = np.array([0.85, 0.66, 0.84, 0.54, 0.72, 0.62])
    step = step_figures(previous, current)
    assert step["ratio"] < 1.0 and not step["rise"]
    # the same first seed alone would read +39%
    assert current[0] / previous[0] > 1.3


def test_paired_seeds_cancel_shared_noise():
    rng = np.random.default_rng(1)
    seed_noise = rng.uniform(0.5, 1.5, 8)            # each seed's draw moves both rungs alike
    previous, current = seed_noise, seed_noise * 1.2
    assert step_figures(previous, current)["rise"]    # +20%, found despite a seed spread of +-50%


def test_mismatched_seeds_are_refused():
    with pytest.raises(ValueError, match="same seeds"):
        step_figures(np.ones(3), np.ones(4))


def test_markdown_marks_the_rise():
    rows = [{"scene": "s/main", "method": "m", "params": "a=1", "per_seed": np.array([1.0, 1.1]), "relmse": 1.05,
             "ci": 0.1, "mean_ratio": 1.0, "top20": 0.1, "step": None},
            {"scene": "s/main", "method": "m", "params": "a=2", "per_seed": np.array([2.0, 2.2]), "relmse": 2.1,
             "ci": 0.2, "mean_ratio": 1.0, "top20": 0.1, "step": step_figures(np.array([1.0, 1.1]), np.array([2.0, 2.2]))}]
    text = markdown(rows)
    assert text.count("**RISE**") == 1 and "2.000 [" in text.splitlines()[-1]


def test_overrides_parse_numbers_and_words():
    from studies.ladder_over_seeds import parse_overrides
    assert parse_overrides(["split_clusters=8", "val_size_scale=0.5", "visibility=hard", "border_gates=true"]) == \
        {"split_clusters": 8, "val_size_scale": 0.5, "visibility": "hard", "border_gates": True}
    with pytest.raises(SystemExit, match="NAME=VALUE"):
        parse_overrides(["split_clusters"])
