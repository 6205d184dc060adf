"""View planning on the AVD move graph under localization uncertainty (docs/planning.md).

``graph`` (the move graph and what the target shows), ``belief`` (the With Uncertainty belief the
robot carries), ``eig`` (expected information gain of a candidate view), ``planners`` (info gain,
known pose, random walk, fixed track, orbit, hindsight), ``episode`` (one run from a start node),
``population`` (every target x start x setting x planner), ``summary`` (per-step metrics, their
CIs and verdicts), ``evaluation`` (the evaluate stage's use of all of it). May import
``pipeline.evaluation``, ``pipeline.method`` and ``pipeline.infra``."""
