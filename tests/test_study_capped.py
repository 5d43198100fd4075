"""A setting of the project's solver whose steps its sweep cap stopped above the tolerance did not
solve to its tolerance: the studies' tables mark it, and never name it the cheapest passing
setting (engines) or the cheapest project setting at least as accurate (frontier), whatever its
criteria and its time (the fast engines study named "residual 1e-06" with 9 capped steps)."""
from dcstudies import engines as E, frontier as F, stability as S


def engine_row(setting, ms, capped):
    return E.Row("mass ratio 400:1", "project", setting, True, True, ms, 0.1, 0.0, 0.0, 0.0, 1.0, float("nan"),
                 0.0, capped)


def test_a_capped_setting_is_marked_and_never_the_cheapest_passing_setting():
    rows = [engine_row("residual 0.01", 0.5, 0), engine_row("residual 1e-06", 0.2, 9)]
    assert E.cheapest(rows)["project"].setting == "residual 0.01"
    assert "| residual 0.01: 0.5 ms |" in E.verdict_table(rows)
    table = E.scene_table(rows)
    assert "| residual 1e-06 (cap hit on 9 steps: not at its tolerance) |" in table, table
    assert E.cheapest(rows[1:])["project"] is None   # (its only passing setting capped: none is named)


def frontier_row(family, setting, ms, residual, capped):
    return F.Row("pile 30", family, setting, True, True, ms, residual, residual, 0.0, 0.01, 0.0, 1.0, capped, 4)


def test_a_capped_setting_is_never_the_frontiers_cheapest_as_accurate():
    rows = [frontier_row("Box2D 2.4.1", "8 iterations", 0.3, 1e-3, None),
            frontier_row("PGS", "residual 1e-06", 0.1, 1e-7, 3), frontier_row("PGS", "residual 1e-08", 0.4, 1e-9, 0)]
    (engine, ours), = F.matches(rows)
    assert ours.setting == "residual 1e-08", ours
    assert "| residual 1e-06 (cap hit on 3 steps: not at its tolerance) |" in F.scene_table(rows)


def test_a_tiny_setting_whose_cap_stops_it_short_is_counted_and_left_out():
    """Measured: 2 sweeps a step to 1e-12 on a stack of 3 cannot reach it; 0.01 within 1000 can."""
    case = S.Case("stack 3", "stack", {"count": 3, "steps": 20}, stack_top=True)
    short = E.Setting("project", "residual 1e-12", "pgs", 2, tolerance=1e-12)
    rows = E.run_scene(case, [E.Setting("project", "residual 0.01", "pgs", 1000, tolerance=1e-2), short])
    assert rows[1].capped > 0 and rows[0].capped == 0, rows
    best = E.cheapest(rows)["project"]
    assert best is None or best.setting == "residual 0.01", best
    assert "residual 1e-12 (cap hit on" in E.scene_table(rows)
