"""Builders that wire Systems into Diagrams (the twin, the estimation diagram, the hybrid torque model) and run them."""
