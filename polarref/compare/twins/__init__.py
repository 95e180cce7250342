"""The paper's Tables 1-3 on the twins: the resumable stages (``pipeline``), the tables (``tables``), what changed with scale (``scale``) and the tables' README (``readme``)."""
