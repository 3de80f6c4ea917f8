"""Push-T demonstrations: replay buffer, normalizer, sequence windows, dataset location."""

from bcbench.data.normalizer import MinMaxNormalizer
from bcbench.data.paths import resolve_dataset
from bcbench.data.replay_buffer import ReplayBuffer, load_replay_buffer
from bcbench.data.sequence import SequenceDataset, make_datasets, split_episodes

__all__ = [
    "MinMaxNormalizer",
    "ReplayBuffer",
    "SequenceDataset",
    "load_replay_buffer",
    "make_datasets",
    "resolve_dataset",
    "split_episodes",
]
