"""Figures as HTML that reads offline (softpend.study.figures.rl)."""

from __future__ import annotations


def test_offline_animation_html_links_nothing_outside_the_page():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.animation import FuncAnimation

    from softpend.study.figures.rl import offline_jshtml

    fig, ax = plt.subplots()
    (line,) = ax.plot([0, 1], [0, 0])
    animation = FuncAnimation(fig, lambda i: line.set_ydata([0, i]) or (line,), frames=3)
    html = offline_jshtml(animation)
    plt.close(fig)
    assert "https://" not in html and "fa fa-play" in html and "<script" in html
