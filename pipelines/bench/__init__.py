"""Benchmarks and sweeps: the paper's tables on the Car Park (`carpark`), the Freiburg and speed suites
(`suites`, with GMapping beside), sweeps over logs and parameters (`sweep`), memory (`memory`)."""
