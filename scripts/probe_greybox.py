"""Per-seed rows of the grey-box route (PRB rod and continuum beam), stored for the book and the closing note.

    .venv/bin/python scripts/probe_greybox.py [--seeds 10] [--out book/records/greybox_route.json]
"""

import argparse
import json

from softpend.study.data_efficiency import greybox_route_figures, greybox_route_rows

parser = argparse.ArgumentParser()
parser.add_argument("--seeds", type=int, default=10)
parser.add_argument("--out", default="book/records/greybox_route.json")
args = parser.parse_args()
rows = {plant: greybox_route_rows(plant, range(args.seeds)) for plant in ("prb", "beam")}
figures = greybox_route_figures(rows["prb"], "greybox", 5.0)
figures.update(greybox_route_figures(rows["beam"], "greybox_beam", 15.0))
with open(args.out, "w") as handle:
    json.dump({"command": "scripts/probe_greybox.py", "figures": figures, "rows": rows}, handle, indent=1, default=str)
print(json.dumps(figures, indent=1))
