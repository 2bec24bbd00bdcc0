"""A product library as a shop catalogue: each product's photos and dimensions by product id.

The picking nodes resolve an order's product id through this; it lives beside the simulator because a
product without its own photos is photographed here (rendered catalogue views).
"""

from __future__ import annotations

import numpy as np

from binpick.core.files import read_image
from binpick.sim.products import ProductLibrary, product_dimensions


class Catalogue:
    """Photos (each with its product mask, or None for a user's own photo) and catalogue dimensions of
    the products in ``library``; rendered views are made once per product and kept."""

    def __init__(self, library: ProductLibrary) -> None:
        self.library = library
        self._photos: dict[str, list[tuple[np.ndarray, np.ndarray | None]]] = {}

    def photos(self, product_id: str) -> list[tuple[np.ndarray, np.ndarray | None]]:
        """The user's own photos where the product has them, else its rendered catalogue views."""
        if product_id not in self._photos:
            from binpick.sim.photos import catalogue_photos

            product = self.library[product_id]
            self._photos[product_id] = ([(read_image(path, keep_alpha=True), None) for path in product.photos]
                                        if product.photos else catalogue_photos(product))
        return self._photos[product_id]

    def size(self, product_id: str) -> tuple[float, float, float]:
        """Catalogue dimensions (m) of a product."""
        return product_dimensions(self.library[product_id])
