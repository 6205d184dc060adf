"""HTML and PNG reports, one sub-room per page (``main``, ``simulate``, ``compare``, ``study``) and
``shared`` for what every page uses (HTML builder, number formatter, figure helpers, run artifacts).
Pages import ``shared``, never each other."""
