"""``odofuse teach``: one self-contained interactive HTML page of the library's models.

:func:`~odofuse.teaching.web.page.build_page` inlines ``page.css``, ``model.js`` (the
library's equations in JavaScript, each function naming the Python one it mirrors) and
``app.js`` (the four panels) into ``page.html`` with the panel defaults and the drive zoo
computed here by the library; :func:`~odofuse.teaching.web.page.write_page` writes it.
"""

from odofuse.teaching.web.page import build_page, drive_specs, page_config, write_page

__all__ = ["build_page", "drive_specs", "page_config", "write_page"]
