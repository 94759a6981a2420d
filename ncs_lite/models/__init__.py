"""dSLATE's parts, a file per concept: dVAE, slot attention (over tokens or a pixel CNN),
SLATE decoder and dynamics (both built of transformer.py's one `Block`), the auxiliary
mixture decoder, and the type/state `split` of a slot."""
import torch

from .decoder import TransformerDecoder
from .dslate import MODEL_VERSION, DSlate, SlotInference
from .dvae import DVAE, cosine_anneal, tau_schedule
from .dynamics import Dynamics
from .mixture_decoder import MixtureDecoder
from .pixel_encoder import PixelEncoder
from .slot_attention import SlotAttention
from .split import split

__all__ = ["DVAE", "DSlate", "Dynamics", "MODEL_VERSION", "MixtureDecoder", "PixelEncoder",
           "SlotAttention", "SlotInference", "TransformerDecoder", "cosine_anneal", "split", "tau_schedule"]

# Once slot attention commits, softmax weights underflow into denormal floats, and CPU
# matmuls over denormals are many times slower (a `reduced` run slowed mid-run: docs/HISTORY.md,
# "Moved from the docstrings"). Flush them to zero. The flag is per thread and worker threads
# copy it when they start, so it is set here, at import, before torch starts its thread pool.
torch.set_flush_denormal(True)
