"""Plant seconds each route needs to balance (``softpend bench --only data_efficiency``)."""

from __future__ import annotations

from softpend.study.data_efficiency import greybox_route_figures, greybox_route_rows


def bench_data_efficiency(seeds: tuple[int, ...] = tuple(range(10))) -> dict[str, float]:
    """The grey-box route on the PRB rod and on the continuum beam (the PRB model fitted to beam data), ten seeds
    each: median and worst plant seconds to balance the fresh report starts, seeds balanced (within 5 s on the PRB
    rod, 15 s on the beam)."""
    figures = greybox_route_figures(greybox_route_rows("prb", seeds), "greybox", 5.0)
    figures.update(greybox_route_figures(greybox_route_rows("beam", seeds), "greybox_beam", 15.0))
    return figures
