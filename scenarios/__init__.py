"""Scenario programs over tracks and the map, answered per object and per frame.

A description in people's words ("vehicle with a bicycle to its right") compiles to a program
(:mod:`scenarios.compiler`), a typed tree of predicates on one object, relations between objects and
temporal composition (:mod:`scenarios.program`). A program runs vectorised over every object ×
frame of a log on its cached features (:mod:`scenarios.features`) and answers which objects it refers
to at which frames, with the objects they relate to (:class:`scenarios.answer.LogAnswer`): the
answer of Argoverse 2's scenario-mining task (:mod:`scenarios.submission`).
"""
