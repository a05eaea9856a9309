"""Data fusion: pan-sharpening (component substitution and multiresolution analysis) and its quality
indices (Wald's protocol: ERGAS, SAM, Q2n, UIQI, SCC; without reference: QNR)."""

from ._quality import (
    assess as assess,
    degrade as degrade,
    ergas as ergas,
    q2n as q2n,
    qnr as qnr,
    sam as sam,
    scc as scc,
    uiqi as uiqi,
    wald_protocol as wald_protocol,
)
from ._sharpen import METHODS as METHODS, Sharpened as Sharpened, mtf_sigma as mtf_sigma, pansharpen as pansharpen
