"""Warehouse data and picking: bin-scene data sets labelled by trial grasps (thesis §5.4.4, §6.3)."""
