"""The built-in synthetic sparring bout: the embedded demo and the test fixture.

Two orthodox boxers (1.70 m and 1.85 m) in a 5x5 m ring, scripted with footwork on
planted feet, jabs, crosses, hooks, slips and clinches; a calibrated rig of 2-8 cameras;
simulated 2D detections with noise, occlusion, misses, a bystander and track-id swaps.
"""

from pipeline.synthetic.bout import SyntheticBout, make_bout
from pipeline.synthetic.config import SyntheticConfig
from pipeline.synthetic.session import make_demo_session, write_session
from pipeline.synthetic.skeleton import SOLE_HEIGHT_M

__all__ = [
    "SOLE_HEIGHT_M",
    "SyntheticBout",
    "SyntheticConfig",
    "make_bout",
    "make_demo_session",
    "write_session",
]
