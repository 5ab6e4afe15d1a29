"""HTTP client of the cornerman REST API (see the API contract), used by the viewer.

The viewer never writes session files: every edit goes through these calls with the
user's bearer token, so the server checks roles and records authorship.
"""

from __future__ import annotations

import logging
from pathlib import Path
from typing import Any

import httpx

log = logging.getLogger(__name__)

TERMINAL_JOB_STATES = ("done", "failed", "cancelled")


class ApiError(ValueError):
    """A non-2xx answer: ``status`` and the server's ``detail``."""

    def __init__(self, method: str, url: str, status: int, detail: str) -> None:
        super().__init__(f"{method} {url}: HTTP {status}: {detail}")
        self.status = status
        self.detail = detail


class ApiClient:
    """Thin typed wrapper over ``httpx.Client`` with ``Authorization: Bearer <token>``.

    ``transport`` lets tests plug in ``httpx.ASGITransport``/``MockTransport``.
    """

    def __init__(
        self,
        api_url: str,
        token: str,
        timeout_s: float = 10.0,
        transport: httpx.BaseTransport | None = None,
        http: httpx.Client | None = None,
    ) -> None:
        base = api_url.rstrip("/")
        if not base.endswith("/api"):
            base += "/api"
        self.base_url = base
        headers = {"Authorization": f"Bearer {token}"}
        if http is not None:  # e.g. a FastAPI TestClient (an httpx.Client) in tests
            http.base_url = httpx.URL(base + "/")
            http.headers.update(headers)
            self._http = http
        else:
            self._http = httpx.Client(base_url=base, headers=headers, timeout=timeout_s, transport=transport)

    def close(self) -> None:
        self._http.close()

    def _request(self, method: str, path: str, **kw: Any) -> Any:
        try:
            r = self._http.request(method, path, **kw)
        except httpx.HTTPError as e:
            raise ApiError(method, self.base_url + path, 0, f"connection failed: {e}") from e
        if r.status_code >= 400:
            try:
                detail = str(r.json().get("detail", r.text))
            except ValueError:
                detail = r.text
            raise ApiError(method, self.base_url + path, r.status_code, detail)
        if not r.content:
            return None
        return r.json()

    # --- identity and sessions -------------------------------------------------------
    def health(self) -> dict:
        return self._request("GET", "/health")

    def me(self) -> dict:
        """``{"name", "role"}`` of the token's user."""
        return self._request("GET", "/me")

    def sessions(self) -> list[dict]:
        return self._request("GET", "/sessions")

    def session(self, session_id: str) -> dict:
        return self._request("GET", f"/sessions/{session_id}")

    def find_session_id(self, session_dir: Path) -> str:
        """The id of the session whose ``folder`` is ``session_dir``; ``ValueError`` when none is."""
        want = Path(session_dir).resolve()
        for s in self.sessions():
            folder = s.get("folder")
            if folder and Path(folder).resolve() == want:
                return str(s["id"])
        raise ValueError(f"no session of the API at {self.base_url} has folder {want}")

    def status(self, session_id: str) -> dict[str, str]:
        return self._request("GET", f"/sessions/{session_id}/status")["stages"]

    def identities(self, session_id: str) -> list[dict]:
        return self._request("GET", f"/sessions/{session_id}/identities")

    # --- annotations ----------------------------------------------------------------
    def annotations(self, session_id: str, include_superseded: bool = False) -> list[dict]:
        params = {"include_superseded": "true" if include_superseded else "false"}
        return self._request("GET", f"/sessions/{session_id}/annotations", params=params)

    def history(self, session_id: str) -> list[dict]:
        """Every edit of the session, newest first, with author, time, summary and state."""
        return self._request("GET", f"/sessions/{session_id}/annotations/history")

    def add_annotation(self, session_id: str, annotation: dict, rerun: bool = True) -> dict:
        """Store an edit (a ``pipeline.schema.annotations`` dict); -> ``{annotation, job, stale_from}``."""
        return self._request("POST", f"/sessions/{session_id}/annotations", json={"annotation": annotation, "rerun": rerun})

    def undo(self, annotation_id: str | int, rerun: bool = True) -> dict:
        return self._request("POST", f"/annotations/{annotation_id}/undo", json={"rerun": rerun})

    def redo(self, annotation_id: str | int, rerun: bool = True) -> dict:
        return self._request("POST", f"/annotations/{annotation_id}/redo", json={"rerun": rerun})

    # --- jobs -----------------------------------------------------------------------
    def job(self, job_id: str | int) -> dict:
        return self._request("GET", f"/jobs/{job_id}")

    def jobs(self, session_id: str | None = None, status: str | None = None) -> list[dict]:
        params = {k: v for k, v in (("session_id", session_id), ("status", status)) if v is not None}
        return self._request("GET", "/jobs", params=params)

    def start_job(self, session_id: str, from_stage: str | None = None, to_stage: str | None = None, force: bool = False) -> dict:
        body: dict[str, Any] = {"session_id": session_id, "force": force}
        if from_stage:
            body["from_stage"] = from_stage
        if to_stage:
            body["to_stage"] = to_stage
        return self._request("POST", "/jobs", json=body)
