"""Plant seconds each route needs to balance (``softpend bench --only data_efficiency``)."""

from __future__ import annotations

import math

from softpend.study import data_efficiency as de

#: Fresh nominal twin starts of ``mpc_rig_*`` (the first report seeds, as the ``rig_control`` group) and their length.
RIG_STARTS = 10
RIG_DURATION_S = 10.0


def bench_data_efficiency(seeds: tuple[int, ...] = tuple(range(10))) -> dict[str, float]:
    """Median and worst plant seconds to balance the fresh report starts, and seeds balanced, of the grey-box route
    (``greybox_beam``: PRB model fitted to beam data) and the planner (``mpc``: PRB-residual model, ``mpc_blackbox``:
    black-box ensemble, ``mpc_beam``: on the beam); the planner's plant seconds over PILCO's (NaN unless the book's
    PILCO runs are trained); ``mpc_rig_*``: the seed-0 planner on the nominal twin."""
    from softpend.study.presets import PILCO_BOOK, REPORT_SEEDS
    from softpend.study.rig_runs import planner_twin_figures

    figures = de.greybox_route_figures(de.greybox_route_rows("prb", seeds), "greybox", 5.0)
    figures.update(de.greybox_route_figures(de.greybox_route_rows("beam", seeds), "greybox_beam", 15.0))
    mpc = de.planner_rows("residual", seeds)
    figures.update(de.greybox_route_figures(mpc, "mpc", 15.0))
    figures.update(de.greybox_route_figures(de.planner_rows("ensemble", seeds), "mpc_blackbox", 15.0))
    figures.update(de.greybox_route_figures(de.planner_rows("residual", seeds, plant="beam"), "mpc_beam", 30.0))
    pilco = de.pilco_rows_if_trained(seeds, PILCO_BOOK.runs_root)
    figures["pilco_book_runs_found"] = float(pilco is not None)
    mpc_s = {r["seed"]: r["real_s_to_balance"] for r in mpc}
    ratio = math.nan if pilco is None else de.paired_ratio(mpc_s, {r["seed"]: r["plant_s_to_balance"] for r in pilco})
    figures["mpc_over_pilco_real_s_ratio"] = ratio
    rig = planner_twin_figures(REPORT_SEEDS[:RIG_STARTS], RIG_DURATION_S)
    for key in ("successes", "step_ms_p95", "step_ms_max", "control_period_ms", "steps_over_period"):
        figures[f"mpc_rig_{key}"] = float(rig[key])
    return figures
