"""The ROS 2 node: a thin shell over core.session (parameters <-> settings, services, diagnostics)."""
