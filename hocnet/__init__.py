"""hocnet: track-before-detect for dim multiple moving targets, as PyTorch modules."""

__version__ = "0.1.0"
