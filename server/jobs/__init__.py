"""Job execution: worker processes claim queued jobs; executors run the pipeline stages."""

from server.jobs.executors import Executor, JobSpec, LocalExecutor, RunHandle, make_executor
from server.jobs.worker import Worker, run_worker

__all__ = ["Executor", "JobSpec", "LocalExecutor", "RunHandle", "Worker", "make_executor", "run_worker"]
