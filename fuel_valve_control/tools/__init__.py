"""Tools: offline simulator, scenarios and demand profiles, demo launcher, recorder, report, metrics, plotting."""
