"""Where the model fails and which physical effect is missing.
May import: io, terms, fit, pipeline, fleet.

:func:`diagnose` (:mod:`.steps`) runs the diagnosis as named steps, each returning a frozen
finding (:mod:`.findings`), and builds the :class:`Diagnosis` once (:mod:`.diagnosis`). One
module per question: :mod:`.where` (where the model fails), :mod:`.effects` (which effect
is missing), :mod:`.naming` (which term to offer), :mod:`.sessions` (how a calibration
carries over to another session), :mod:`.verdict` (the verdict and the advice); :mod:`.lab`
(an effect fixed in the lab, seen through the turning table; an offset per mounting) and
:mod:`.between` (a calibration that fits every temperature point and misses between them)
test for findings no term can hold; :mod:`.evaluation` fits and validates the models they
compare, :mod:`.stats` holds the tails and bounds of the tests.

Three questions, answered from the observations alone:

1. **Does the model explain the data?** The in-sample residuals of every fit, divided by
   each observation's noise floor, should scatter like unit normals: χ² against its
   degrees of freedom, overall and per output axis. When the session's noise model has bias
   instability or rate random walk, χ² and the F-tests below come from the generalised
   least-squares fits that account for the holds' shared wander (:func:`gyrocal.fit.model.fit`).
2. **Where does the excess live?** For every covariate the log offers (temperature, its
   rate, the reference rate, its magnitude and direction, the mount, the accelerometer,
   time, hold length), the share of the excess χ² that the covariate's bins account for,
   beyond what bins explain by chance. Ranked, plus heat maps (mount × rate, temperature ×
   rate).
3. **Which effect is missing?** Every candidate term (the library's, those the user names,
   those of the user's term files) is added to the model in turn; the extended model is
   refitted and validated the same way. Candidates are ranked by the validation RMS they
   reach; each gets a nested-model F-test against the base model and the fitted size of the
   effect in physical units. The significance level is family-wise: half goes to the χ²
   test of question 1, half is shared (Bonferroni) by the candidates, so on data the model
   explains the diagnosis raises a false alarm at most that often.
"""

from .diagnosis import Diagnosis
from .effects import TIME_DRIFT, Candidate, mark_ties
from .evaluation import (
    Evaluation,
    add_term_option,
    candidate_terms,
    config_line,
    evaluate,
    evaluation_of,
    extended,
)
from .sessions import carry_over, repeat_p_value, shared_fraction, unrepeated_p_value
from .stats import chance_bound, chi2_ppf, chi2_sf, explained_tolerance, f_sf, fisher_combined
from .steps import diagnose
from .where import COVARIATES

__all__ = [
    "COVARIATES",
    "TIME_DRIFT",
    "Candidate",
    "Diagnosis",
    "Evaluation",
    "add_term_option",
    "candidate_terms",
    "carry_over",
    "chance_bound",
    "chi2_ppf",
    "chi2_sf",
    "config_line",
    "diagnose",
    "evaluate",
    "evaluation_of",
    "explained_tolerance",
    "extended",
    "f_sf",
    "fisher_combined",
    "mark_ties",
    "repeat_p_value",
    "shared_fraction",
    "unrepeated_p_value",
]
