"""Per-seed rows of the grey-box route (PRB rod and continuum beam), stored for the book and the closing note.

.venv/bin/python scripts/probe_greybox.py [--seeds 10] [--out book/records/greybox_route.json]
"""

import argparse
import json

from softpend.study.data_efficiency import greybox_route_figures, greybox_route_rows
from softpend.study.records import record_text

parser = argparse.ArgumentParser()
parser.add_argument("--seeds", type=int, default=10)
parser.add_argument("--out", default="book/records/greybox_route.json")
args = parser.parse_args()
rows = {plant: greybox_route_rows(plant, range(args.seeds)) for plant in ("prb", "beam")}
figures = greybox_route_figures(rows["prb"], "greybox", 5.0)
figures.update(greybox_route_figures(rows["beam"], "greybox_beam", 15.0))
record = {
    "title": "Grey-box route (excite, identify the PRB rod, swing-up + LQR on the estimate) on the PRB rod and the beam",
    "command": "scripts/probe_greybox.py " + " ".join(f"--{k} {v}" for k, v in vars(args).items()),
    "settings": {"seeds": args.seeds},
    "figures": figures,
    "rows": rows["prb"] + rows["beam"],
}
with open(args.out, "w") as handle:
    handle.write(record_text(record))
print(json.dumps(figures, indent=1))
