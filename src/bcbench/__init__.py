"""bcbench: visuomotor behavior cloning on Push-T, task accuracy against real-time inference latency.

The public policy interface (torch-free, so that `import bcbench` stays light):

    from bcbench import ChunkPolicy            # what every command takes: eval, latency, realtime, studies
    isinstance(my_policy, bcbench.ChunkPolicy)  # a structural check (see bcbench.interface for the contract)
"""

from bcbench.interface import (
    ChunkPolicy,
    FilmSplittable,
    GenerativePolicy,
    Observation,
    RunInfo,
    SeededPolicy,
    SelfTimedPolicy,
    example_observation,
)

__version__ = "0.1.0"

__all__ = ["ChunkPolicy", "FilmSplittable", "GenerativePolicy", "Observation", "RunInfo", "SeededPolicy",
           "SelfTimedPolicy", "__version__", "example_observation"]
