"""The monitor pipeline: the one object the node and the offline tools drive, and the parts it owns."""
