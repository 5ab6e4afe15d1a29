"""Identity colours: one fixed colour per global person id (the corners of the ring)."""

from __future__ import annotations

from dataclasses import dataclass

UNASSIGNED_RGB: tuple[int, int, int] = (150, 150, 150)
"""Grey for detections attributed to nobody (``person = -1``) or not yet associated."""

DEFAULT_IDENTITIES: tuple[tuple[str, str, str], ...] = (
    ("Red", "#d62728", "red"),
    ("Blue", "#1f77b4", "blue"),
)
# Further persons (rare: a third athlete in sparring) get distinct, non-corner colours.
_EXTRA_HEX: tuple[str, ...] = ("#2ca02c", "#ff7f0e", "#9467bd", "#8c564b")


def hex_to_rgb(color: str) -> tuple[int, int, int]:
    """``"#d62728"`` -> ``(214, 39, 40)``; ``ValueError`` on anything else."""
    c = color.strip().lstrip("#")
    if len(c) != 6:
        raise ValueError(f"colour must be #rrggbb, got {color!r}")
    try:
        return int(c[0:2], 16), int(c[2:4], 16), int(c[4:6], 16)
    except ValueError:
        raise ValueError(f"colour must be #rrggbb, got {color!r}") from None


@dataclass(frozen=True)
class Identity:
    """Display identity of one global person id."""

    person_id: int
    name: str
    color_hex: str

    @property
    def rgb(self) -> tuple[int, int, int]:
        return hex_to_rgb(self.color_hex)

    @property
    def bgr(self) -> tuple[int, int, int]:
        r, g, b = self.rgb
        return b, g, r


def default_identity(person_id: int, name: str = "") -> Identity:
    if 0 <= person_id < len(DEFAULT_IDENTITIES):
        n, c, _ = DEFAULT_IDENTITIES[person_id]
        return Identity(person_id, name or n, c)
    return Identity(person_id, name or f"P{person_id}", _EXTRA_HEX[person_id % len(_EXTRA_HEX)])


class IdentityPalette:
    """person id -> Identity, from the API's ``/identities`` list or the defaults."""

    def __init__(self, identities: list[Identity] | None = None, athletes: tuple[str, ...] = ()) -> None:
        self._by_id: dict[int, Identity] = {}
        for i, name in enumerate(athletes):
            self._by_id[i] = default_identity(i, name)
        for ident in identities or []:
            self._by_id[ident.person_id] = ident

    @classmethod
    def from_api(cls, rows: list[dict], athletes: tuple[str, ...] = ()) -> IdentityPalette:
        """Build from ``GET /api/sessions/{id}/identities`` rows (``person_id``, ``name``, ``color``)."""
        out = []
        for r in rows:
            try:
                out.append(Identity(int(r["person_id"]), str(r.get("name", "")), str(r["color"])))
                hex_to_rgb(out[-1].color_hex)
            except (KeyError, TypeError, ValueError) as e:
                raise ValueError(f"identities: bad row {r!r}: {e}") from e
        return cls(out, athletes)

    def get(self, person_id: int) -> Identity | None:
        """The identity of ``person_id`` (``None`` for ``-1`` = unassigned)."""
        if person_id < 0:
            return None
        if person_id not in self._by_id:
            self._by_id[person_id] = default_identity(person_id)
        return self._by_id[person_id]

    def rgb(self, person_id: int) -> tuple[int, int, int]:
        ident = self.get(person_id)
        return UNASSIGNED_RGB if ident is None else ident.rgb

    def bgr(self, person_id: int) -> tuple[int, int, int]:
        r, g, b = self.rgb(person_id)
        return b, g, r

    def name(self, person_id: int) -> str:
        ident = self.get(person_id)
        return "unassigned" if ident is None else ident.name


class StalePalette(IdentityPalette):
    """The identities of an out-of-date association: every box grey, every name marked "(old)",
    so that labels from before an edit are never read as the edit's result."""

    def __init__(self, base: IdentityPalette) -> None:
        super().__init__()
        self._base = base

    def get(self, person_id: int) -> Identity | None:
        return self._base.get(person_id)

    def rgb(self, person_id: int) -> tuple[int, int, int]:
        return UNASSIGNED_RGB

    def name(self, person_id: int) -> str:
        return f"{self._base.name(person_id)} (old)"
