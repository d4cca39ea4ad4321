"""Planning from the tissue as it is now: candidate tool insertions toward a target, rolled
out in a batch from a snapshot and ranked by the implicit Euler energy they add
(``insertion``). Built on :mod:`..sim`.
"""
