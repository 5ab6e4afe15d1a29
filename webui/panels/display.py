"""Display options: which 3D result to show (filtered / fit / physics) and which layers."""

from __future__ import annotations

from dataclasses import dataclass

import viser

from pipeline.schema.sources import RESULT_LABELS
from webui.scope import Scope

SOURCE_LABELS: dict[str, str] = RESULT_LABELS


@dataclass
class DisplayHandles:
    source: viser.GuiDropdownHandle[str]
    skeleton: viser.GuiCheckboxHandle
    body: viser.GuiCheckboxHandle
    physics: viser.GuiCheckboxHandle
    reload: viser.GuiButtonHandle


def source_options(available: list[str]) -> tuple[str, ...]:
    """Dropdown labels of the sources present (all three listed when none is, for a stable UI)."""
    keys = [k for k in SOURCE_LABELS if k in available] or list(SOURCE_LABELS)
    return tuple(SOURCE_LABELS[k] for k in keys)


def label_to_source(label: str) -> str:
    for k, v in SOURCE_LABELS.items():
        if v == label:
            return k
    raise ValueError(f"unknown source label {label!r}; known: {list(SOURCE_LABELS.values())}")


def make_display(server: Scope, available: list[str]) -> DisplayHandles:
    opts = source_options(available)
    source = server.gui.add_dropdown("3D source", opts, initial_value=opts[-1] if opts else None)
    skeleton = server.gui.add_checkbox("Keypoints and bones", initial_value=True)
    body = server.gui.add_checkbox("Body mesh (fit)", initial_value=True)
    physics = server.gui.add_checkbox("Physics geoms", initial_value=True)
    reload = server.gui.add_button("Reload results")
    return DisplayHandles(source, skeleton, body, physics, reload)
