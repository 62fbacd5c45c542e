"""The GitHub workflow that tests, builds and publishes the book is valid against GitHub's workflow schema
(check-jsonschema ships the schema, so this runs offline) and does what CONTRIBUTING.md says it does."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import yaml

ROOT = Path(__file__).resolve().parents[1]
WORKFLOW = ROOT / ".github" / "workflows" / "book.yml"
CHECK_JSONSCHEMA = Path(sys.executable).with_name("check-jsonschema")


def check(path: Path) -> subprocess.CompletedProcess:
    # any attempt to reach the network goes to a closed port: the schema must come from the package itself
    env = {**os.environ, "HTTP_PROXY": "http://127.0.0.1:9", "HTTPS_PROXY": "http://127.0.0.1:9", "NO_PROXY": ""}
    return subprocess.run(
        [str(CHECK_JSONSCHEMA), "--builtin-schema", "vendor.github-workflows", str(path)],
        capture_output=True,
        text=True,
        env=env,
        timeout=120,
    )


def test_the_workflow_is_valid_and_a_broken_copy_is_not(tmp_path):
    result = check(WORKFLOW)
    assert result.returncode == 0, result.stdout + result.stderr

    text = WORKFLOW.read_text()
    broken = tmp_path / "book.yml"
    broken.write_text(
        text.replace("    runs-on: ubuntu-latest\n", "    runs-on: ubuntu-latest\n    timeout-minutes: soon\n", 1)
    )
    result = check(broken)
    assert result.returncode != 0 and "timeout-minutes" in result.stdout + result.stderr, result.stdout
    no_steps = tmp_path / "no_steps.yml"
    no_steps.write_text(text.replace("    steps:\n", "    stages:\n"))
    assert check(no_steps).returncode != 0


def test_the_workflow_tests_builds_from_the_cache_and_deploys_to_pages():
    workflow = yaml.safe_load(WORKFLOW.read_text())
    jobs = workflow["jobs"]

    def runs(job):
        return [step.get("run", "") for step in jobs[job]["steps"]]

    def uses(job):
        return {step["uses"].split("@")[0]: step.get("with", {}) for step in jobs[job]["steps"] if "uses" in step}

    assert "make test" in runs("test")
    assert jobs["book"]["needs"] == "test" and "make book" in runs("book")
    cache = uses("book")["actions/cache"]
    assert set(cache["path"].split()) == {"runs", "book/_generated"}
    assert "hashFiles('environment.lock', 'softpend/**')" in cache["key"]
    assert uses("book")["actions/upload-pages-artifact"]["path"] == "_build/html"
    deploy = jobs["deploy"]
    assert deploy["needs"] == "book" and "actions/deploy-pages" in uses("deploy")
    assert deploy["permissions"] == {"pages": "write", "id-token": "write"}
    assert deploy["environment"]["name"] == "github-pages"
