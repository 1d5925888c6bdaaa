"""proprio: simulate a torque-sensing arm, identify its inverse dynamics, estimate external wrenches from joint
torques, and diagnose the gap between a simulation model and measured data."""

__version__ = "0.1.0"
