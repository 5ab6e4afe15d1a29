"""The bout report: a printable, self-contained HTML page of a session's boxing analytics."""

from pipeline.report.data import ReportData, ReportOptions, load_report_data, slice_bout
from pipeline.report.html import render_report

__all__ = ["ReportData", "ReportOptions", "load_report_data", "render_report", "slice_bout"]
