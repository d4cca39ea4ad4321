"""Planning from the tissue as it is now: candidate tool insertions toward a target, rolled
out in a batch from a snapshot and ranked by the implicit Euler energy they add
(``insertion``); and the model-predictive grasp controller that drives a tissue point to a target on its own
model, synced to tracked points (``control``, ``observe``). Built on :mod:`..sim`.
"""
