"""The diagnosis of the gap between a model and a log, in stages a reader can follow in order.

1. ``start``: the log checked, its initial state and the floor the gap is measured from;
2. ``blocks``: the log split into training and scored blocks;
3. ``where``: where the gap lies (phase, level, band, time, airspeed);
4. ``search`` (over ``problem``'s fits, on ``pool``'s workers): every effect fitted as an augmentation,
   round by round;
5. ``selection``: what a decision (``options``) names of the explored rounds, with ``readings``, the
   physical re-readings of a tendon sheath;
6. ``transfer``: the floor raised where the bench's model-error correction does not carry to the log;
7. ``sizing``: the named effects sized on every analysed sample;
8. ``left``: what is left over;
9. ``report`` and ``summary``: REPORT.json and its text.

``pipeline.diagnose`` runs them; ``check`` scores a model on a check log of another input.
"""

from warpbridge.model.diagnosis.options import DECISION_GRID, Decision, DiagnoseOptions
from warpbridge.model.diagnosis.pipeline import Diagnosis, diagnose
from warpbridge.model.diagnosis.report import REPORT_FORMAT
from warpbridge.model.diagnosis.summary import summary_lines

__all__ = ["DECISION_GRID", "REPORT_FORMAT", "Decision", "DiagnoseOptions", "Diagnosis", "diagnose", "summary_lines"]
