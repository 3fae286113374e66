"""Identification of the Bouc-Wen model from a log, in steps a reader can follow in order.

1. ``data``: the log checked, normalised and split into a training and a held-out part;
2. ``excitation``: what the training part excites, and what it leaves open;
3. ``design`` (over ``space``'s search vectors): the start design and, step 4, the linear solve of every
   trial shape; ``servo``: the servo's lag in front of the model, scanned on the same solves;
5. ``refine`` (on ``path``'s compressed training path): the local refinement of the best starts, and when
   they disagree the escalation, ``global_search``;
6. ``delay``: the transport delay in front of the model;
7. and 8. ``checks``: a backbone folding inside the working range, a fit worse than a line, and whether
   the held-out part supports the model;
9. the model-error model is the CLI's step (``model.model_error``);
10. ``uncertainty``: a 95 % interval for every parameter;

and ``result``: what identification returns. ``pipeline.identify`` runs them (the method is described
there).
"""

from warpbridge.model.identification.checks import Support, support_check, working_range
from warpbridge.model.identification.data import check_log
from warpbridge.model.identification.delay import DELAY_GRID_S
from warpbridge.model.identification.excitation import Excitation, excitation_check
from warpbridge.model.identification.pipeline import identify
from warpbridge.model.identification.refine import SearchTrace
from warpbridge.model.identification.result import IdentResult
from warpbridge.model.identification.servo import LAG_GRID_S
from warpbridge.model.identification.space import fold_depth

__all__ = ["DELAY_GRID_S", "LAG_GRID_S", "Excitation", "IdentResult", "SearchTrace", "Support", "check_log",
           "excitation_check", "fold_depth", "identify", "support_check", "working_range"]
