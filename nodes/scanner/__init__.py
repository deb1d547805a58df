"""The scan: the robot scanner and its plan, control and supervision, touch-off and surface following, the adaptive planner, and the simpler pose sources (linear stage, static pose)."""
