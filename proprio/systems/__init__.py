"""Drake Systems, one family per module, with named ports in SI units: trajectory sources and RFMA, the joint drive, the
sensors, the RBD backbone, the residual network, the wrench observers and the causal conditioning stage. They wrap
the algorithms and the joint-effect library; they never import diagrams or workflows."""
