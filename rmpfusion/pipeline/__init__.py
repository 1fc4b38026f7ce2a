"""An experiment as stages (collect, fit, evaluate, report) over a validated run configuration."""
