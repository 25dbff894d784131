"""`python -m pipelines.cli`: the `gslam` command."""

from pipelines.cli import run

run()
