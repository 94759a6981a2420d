"""dSLATE's parts, a file per concept: dVAE, slot attention (over tokens or a pixel CNN),
SLATE decoder, dynamics, and the auxiliary mixture decoder."""
from .decoder import TransformerDecoder
from .dslate import MODEL_VERSION, DSlate, SlotInference
from .dvae import DVAE, cosine_anneal, tau_schedule
from .dynamics import Dynamics
from .mixture_decoder import MixtureDecoder
from .pixel_encoder import PixelEncoder
from .slot_attention import SlotAttention

__all__ = ["DVAE", "DSlate", "Dynamics", "MODEL_VERSION", "MixtureDecoder", "PixelEncoder",
           "SlotAttention", "SlotInference", "TransformerDecoder", "cosine_anneal", "tau_schedule"]
