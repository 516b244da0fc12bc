"""Feature families beyond the paper's histogram, as scikit-learn transformers that also write their
own ONNX nodes: per-pad signals (``signals``), level statistics (``PadStats``), MiniRocket-style
random convolutions (``RandomConvPPV``), the hand-designed baseline (``HandGraphFeatures``) and each
taxel's mean over the window (``ContactImage``)."""

from trainer.features.contact_image import ContactImage
from trainer.features.hand import HandGraphFeatures
from trainer.features.pad_stats import PadStats
from trainer.features.rocket import RandomConvPPV

__all__ = ["ContactImage", "HandGraphFeatures", "PadStats", "RandomConvPPV"]
