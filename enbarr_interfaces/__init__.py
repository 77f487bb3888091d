"""The contract between Enbarr nodes.

Topic names, standard message types, QoS, units and frames (``topics``), message <-> numpy
conversions (``convert``) and the in-process fast path that composed nodes use to hand
messages to each other (``links``).
"""
