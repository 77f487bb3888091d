"""Benchmarks, all behind ``enbarr bench`` (``enbarr_core.commands.bench``).

- ``chain``: the sensor -> actuator chain of a vessel composed in one process, at a rate
  (``--chain rov|saucer``, the default), and a profile's fixed cost (``--profile P --idle``);
- ``profile_run``: a whole profile under ``bringup`` as processes, measured from ``/proc``
  (``--profile P``, with ``--record`` without and then with a bag);
- ``recording``: what the recorder costs per message (``--recording``);
- ``perception``: what one lidar scan costs, scan -> tracked obstacles (``--perception``).

Each prints one JSON line; ``docs/benchmarks.md`` has the figures of ours and how they were
taken.
"""
