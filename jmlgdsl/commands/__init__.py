"""The subcommands of `jmlgdsl`, one module each (see jmlgdsl/cli.py), and what several of them share,
imported from here: argument types (`_types`), the options of the filter (`_filter`), of a diagnosis
(`_diagnosis`), of a fleet and a cluster (`_fleet`) and of a store and its page (`_store`). A module whose
name begins with an underscore is one of these, not a command."""

from ._diagnosis import (add_alarm_options, add_smoothing_options, add_split_options, diagnosis_options,
                         healthy_modes, model_and_options)
from ._filter import add_filter_options, check_particles
from ._fleet import add_cluster_option, add_unit_specs_option
from ._store import STORE_HELP, add_page_options, add_store_password_options, start_page, store_password
from ._types import catch_all, finite, lags, listed, names, positive, probability, whole

__all__ = ["add_alarm_options", "add_smoothing_options", "add_split_options", "diagnosis_options", "healthy_modes",
           "model_and_options", "add_filter_options", "check_particles", "add_cluster_option",
           "add_unit_specs_option", "STORE_HELP", "add_page_options", "add_store_password_options", "start_page",
           "store_password", "catch_all", "finite", "lags", "listed", "names", "positive", "probability", "whole"]
