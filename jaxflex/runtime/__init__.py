"""What runs the physics, apart from it: compiler options (``options``), ahead-of-time compiles and
the lifetime of compiled programs (``compiled``), host threads (``threads``), memo caches (``memo``)
and heap trimming (``heap``). Pools and threads are created on first use. The physics modules
(model, beams, linearized, rollout and its integrator, metrics, rigid, path, blends, profiles,
trajectory) never import this package (tests/test_layout.py)."""
