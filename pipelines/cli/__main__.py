"""`python -m pipelines.cli`: the `gslam` command."""

from pipelines.cli.app import run

run()
