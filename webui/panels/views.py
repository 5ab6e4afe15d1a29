"""Camera frames: one image per view with its overlays, and a button aligning the 3D camera with it."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import viser

from webui.scope import Scope


@dataclass
class ViewsHandles:
    images: dict[str, viser.GuiImageHandle]
    align: dict[str, viser.GuiButtonHandle]


def make_views(server: Scope, camera_names: tuple[str, ...], sizes_wh: list[tuple[int, int]]) -> ViewsHandles:
    images: dict[str, viser.GuiImageHandle] = {}
    align: dict[str, viser.GuiButtonHandle] = {}
    for name, (w, h) in zip(camera_names, sizes_wh, strict=True):
        images[name] = server.gui.add_image(np.zeros((h, w, 3), dtype=np.uint8), label=name, format="jpeg", jpeg_quality=80)
        align[name] = server.gui.add_button(f"View from {name}", hint=f"Align the 3D camera with {name}")
    return ViewsHandles(images, align)
