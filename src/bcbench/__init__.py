"""bcbench: visuomotor behavior cloning on Push-T, task accuracy against real-time inference latency."""

__version__ = "0.1.0"
