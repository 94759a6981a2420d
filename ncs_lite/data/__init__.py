"""The experience buffer: collection, storage and torch datasets."""
from .buffer import (EpisodeDataset, cached_buffer, collect, find_buffer, load_buffer, load_manifest,
                     manifest_hash, record_episode)

__all__ = ["EpisodeDataset", "cached_buffer", "collect", "find_buffer", "load_buffer", "load_manifest", "manifest_hash",
           "record_episode"]
