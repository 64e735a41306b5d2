"""The terms of a call: one typed options class per method (``options``), the method table
(``methods``), argument checks (``validation``), the mixed-units diagnosis (``units``) and
what a call returns (``result``). Every other part of :mod:`masknet.registration` uses them;
they use none of it."""
