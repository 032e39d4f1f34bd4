"""The differentiable path's search: one loop (``loop``), its loss (``objective``), where it starts
(``starts``), what moves get to work with (``trial``) and the moves generators contribute (``moves``)."""
