"""Draw the README's figure, book/_static/swingup.png: the energy swing-up controller on the default rod.

Run from the repository root: ``.venv/bin/python book/_static/readme_figure.py`` (a few seconds).
"""

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

from softpend.control.swingup import EnergySwingUpController  # noqa: E402
from softpend.evaluation import evaluate_controller  # noqa: E402
from softpend.study.figures.rl import plot_swingup  # noqa: E402
from softpend.task import Task  # noqa: E402

task = Task(start="hanging")
result = evaluate_controller(EnergySwingUpController(task.rod), task, seeds=(0,), duration_s=4.0).results[0]
fig = plot_swingup(result, task.make_plant().link_points_m, fig=plt.figure(figsize=(9, 6.5)))
fig.savefig(Path(__file__).with_name("swingup.png"), dpi=80, bbox_inches="tight")
