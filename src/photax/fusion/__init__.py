"""Data fusion: pan-sharpening (component substitution and multiresolution analysis) and its quality
indices (Wald's protocol: ERGAS, SAM, Q2n, UIQI, SCC; without reference: QNR)."""

from ._dask import pansharpen_dask as pansharpen_dask
from ._quality import (
    assess as assess,
)
from ._quality import (
    degrade as degrade,
)
from ._quality import (
    ergas as ergas,
)
from ._quality import (
    q2n as q2n,
)
from ._quality import (
    qnr as qnr,
)
from ._quality import (
    sam as sam,
)
from ._quality import (
    scc as scc,
)
from ._quality import (
    uiqi as uiqi,
)
from ._quality import (
    wald_protocol as wald_protocol,
)
from ._sharpen import METHODS as METHODS
from ._sharpen import Sharpened as Sharpened
from ._sharpen import mtf_sigma as mtf_sigma
from ._sharpen import pansharpen as pansharpen
