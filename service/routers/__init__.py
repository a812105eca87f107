"""HTTP routes: thin functions that parse a request, call :class:`service.jobs.JobService`, answer."""
