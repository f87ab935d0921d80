"""The demo application (``python -m renderer demo``): pipeline cache, simulated and hardware runs, metrics, figures."""
