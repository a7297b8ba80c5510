"""The daemon: input sources, the estimator task, output sinks, learned biases, systemd."""
