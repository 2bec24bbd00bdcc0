"""Warehouse simulation: a product library, bin scenes with an overhead RGB-D camera, shop photos and
a parallel-jaw gripper that labels which instances can be picked (thesis §5.4.4, §6.3)."""

from binpick.sim.own_products import load_products
from binpick.sim.products import Product, ProductLibrary, default_library

__all__ = ["Product", "ProductLibrary", "default_library", "load_products"]
