"""The planning service: a FastAPI jobs API over ``planning.pipeline`` (``scanmill serve``).

``service/`` only translates HTTP into calls of the planning code and stores jobs and their files;
it holds no geometry. Layout: ``settings`` (SCANMILL_* configuration), ``db`` and ``migrations/``
(SQLAlchemy tables, engines, Alembic), ``store`` (the job store on SQLite or PostgreSQL),
``storage`` (files, atomic writes, safe names; local or shared directory), ``backends`` (the
execution interface), ``workers`` (the embedded process-per-job backend), ``celery_app``,
``celery_tasks`` and ``celery_backend`` (the distributed backend), ``intake``
(upload validation), ``jobs`` (the use cases), ``auth``, ``problems`` (RFC 9457), ``limits``
(request sizes), ``routers/`` (thin HTTP routes) and ``app`` (the application factory).
"""
