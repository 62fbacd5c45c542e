"""Plant seconds each route needs to balance (``softpend bench --only data_efficiency``)."""

from __future__ import annotations

import math

from softpend.study.data_efficiency import (
    greybox_route_figures,
    greybox_route_rows,
    paired_ratio,
    pilco_rows_if_trained,
    planner_rows,
)

#: Fresh nominal twin starts of ``mpc_rig_*`` (the first report seeds, as the ``rig_control`` group) and their length.
RIG_STARTS = 10
RIG_DURATION_S = 10.0


def bench_data_efficiency(seeds: tuple[int, ...] = tuple(range(10))) -> dict[str, float]:
    """Median and worst plant seconds to balance the fresh report starts, and seeds balanced, of ten seeds of the
    grey-box route (PRB rod; ``greybox_beam``: the PRB model fitted to beam data) and the planner (``mpc``: the
    PRB-residual model, ``mpc_blackbox``: the black-box ensemble, ``mpc_beam``: on the beam); the planner's plant
    seconds over PILCO's (median over seeds; NaN, with ``pilco_book_runs_found`` 0, unless the book's PILCO runs are
    all trained); ``mpc_rig_*``: the seed-0 planner on the nominal twin (successes, step times against the period)."""
    from softpend.study.presets import PILCO_BOOK, REPORT_SEEDS
    from softpend.study.rig_runs import planner_twin_figures

    figures = greybox_route_figures(greybox_route_rows("prb", seeds), "greybox", 5.0)
    figures.update(greybox_route_figures(greybox_route_rows("beam", seeds), "greybox_beam", 15.0))
    mpc = planner_rows("residual", seeds)
    figures.update(greybox_route_figures(mpc, "mpc", 15.0))
    figures.update(greybox_route_figures(planner_rows("ensemble", seeds), "mpc_blackbox", 15.0))
    figures.update(greybox_route_figures(planner_rows("residual", seeds, plant="beam"), "mpc_beam", 30.0))
    pilco = pilco_rows_if_trained(seeds, PILCO_BOOK.runs_root)
    figures["pilco_book_runs_found"] = float(pilco is not None)
    mpc_s = {r["seed"]: r["real_s_to_balance"] for r in mpc}
    ratio = math.nan if pilco is None else paired_ratio(mpc_s, {r["seed"]: r["plant_s_to_balance"] for r in pilco})
    figures["mpc_over_pilco_real_s_ratio"] = ratio
    rig = planner_twin_figures(REPORT_SEEDS[:RIG_STARTS], RIG_DURATION_S)
    for key in ("successes", "step_ms_p95", "step_ms_max", "control_period_ms", "steps_over_period"):
        figures[f"mpc_rig_{key}"] = float(rig[key])
    return figures
