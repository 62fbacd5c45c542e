"""Plant seconds each route needs to balance (``softpend bench --only data_efficiency``)."""

from __future__ import annotations

from softpend.study.data_efficiency import greybox_route_figures, greybox_route_rows, planner_rows


def bench_data_efficiency(seeds: tuple[int, ...] = tuple(range(10))) -> dict[str, float]:
    """Ten seeds each: the grey-box route on the PRB rod and on the continuum beam (the PRB model fitted to beam
    data), and the planner with the PRB-residual model (``mpc_*``) and the black-box ensemble
    (``mpc_blackbox_*``): median and worst plant seconds to balance the fresh report starts, seeds balanced."""
    figures = greybox_route_figures(greybox_route_rows("prb", seeds), "greybox", 5.0)
    figures.update(greybox_route_figures(greybox_route_rows("beam", seeds), "greybox_beam", 15.0))
    figures.update(greybox_route_figures(planner_rows("residual", seeds), "mpc", 15.0))
    figures.update(greybox_route_figures(planner_rows("ensemble", seeds), "mpc_blackbox", 15.0))
    return figures
