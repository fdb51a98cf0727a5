"""The public API: what ``import capsmech`` offers a script or a notebook, and what the CLI wraps.

Every function takes a database as a loaded object, a shipped database's name (``"tube-paper"``,
see ``capsmech.io.catalog``) or a file path, and measurements as a file path (CSV or ``.xlsx``),
a DataFrame (units in its column names or ``attrs["units"]``) or capsules. Results are pandas
DataFrames, one row per capsule (and law), with a ``flag`` code column (empty when the capsule
was fitted; ``capsmech.inversion.fitting.FLAG_CODES``) and a ``reason`` column in words;
``DataFrame.attrs["units"]`` gives each column's unit. What a user must know but that does not
stop the analysis is a warning of the ``capsmech.errors.CapsmechWarning`` family; what stops it
is a ``CapsmechError`` with a message naming the file, line, field or name at fault.
"""
from __future__ import annotations

import math
import warnings
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, Literal, TypeAlias, cast, overload

import numpy as np
import pandas as pd

from capsmech.errors import CapsmechError, InputWarning, OutsideDatabaseWarning
from capsmech.inversion.fitting import (
    SHEAR_RESULT_UNITS,
    TUBE_RESULT_UNITS,
    add_fold_columns,
    fit_shear_rows,
    fit_tube_rows,
)
from capsmech.inversion.population import PopulationVerdict, population_verdict
from capsmech.inversion.population_report import plot_population as plot_population_rows
from capsmech.io import plausibility
from capsmech.io.database import Database, DatabaseError, ShearDatabase, TubeDatabase, load_database
from capsmech.io.measurement_frames import capsules_from_frame
from capsmech.io.measurements import Capsule, MeasurementError, read_measurements

if TYPE_CHECKING:
    from matplotlib.figure import Figure

    from capsmech.diagnosis.diagnose import Diagnosis
    from capsmech.diagnosis.offcentre import OffcentreTable
    from capsmech.diagnosis.sequential import SequentialDiagnosis
    from capsmech.diagnosis.shear import ShearDiagnosis
    from capsmech.diagnosis.undeclared_tube import Batch
    from capsmech.imaging.shear_plane import ShearExtraction
    from capsmech.inversion.microrheometry import MethodComparison
    from capsmech.io.case import CaseResult

DatabaseLike: TypeAlias = Database | str | Path
CapsulesLike: TypeAlias = pd.DataFrame | Sequence[Capsule] | str | Path
ResultsLike: TypeAlias = pd.DataFrame | Iterable[Mapping[str, Any]] | str | Path


# The flow checked gives the type: load_database makes a TubeDatabase of a tube file, a
# ShearDatabase of a shear one.
@overload
def as_database(database: DatabaseLike, flow: Literal["tube"], caller: str) -> TubeDatabase: ...
@overload
def as_database(database: DatabaseLike, flow: Literal["shear"], caller: str) -> ShearDatabase: ...
@overload
def as_database(database: DatabaseLike, flow: str, caller: str) -> Database: ...
def as_database(database: DatabaseLike, flow: str, caller: str) -> Database:
    """A loaded database of ``flow``: ``database`` itself, or the one its name or path gives.

    Raises
    ------
    DatabaseError
        When the name is unknown, the file unreadable, or the database of another flow.
    """
    db = database if isinstance(database, Database) else load_database(database)
    if db.flow != flow:
        raise DatabaseError(f"{caller}: {_label(db)} is a {db.flow} database; {caller} needs a {flow} database "
                            f"(e.g. '{flow}-paper')")
    return db


def check_laws(database: Database, laws: str | Iterable[str] | None, option: str = "laws") -> list[str]:
    """The law keys asked for (all the database's when None); a single key may be given as a string.

    Raises
    ------
    DatabaseError
        Naming every unknown key and listing the valid ones.
    """
    if laws is None:
        return list(database.laws)
    keys = [laws] if isinstance(laws, str) else list(laws)
    unknown = [key for key in keys if key not in database.laws]
    if unknown:
        raise DatabaseError(f"{option}: {_label(database)} has no law {', '.join(repr(k) for k in unknown)}; "
                            f"valid laws: {', '.join(database.laws)}")
    if not keys:
        raise DatabaseError(f"{option}: no law given; valid laws: {', '.join(database.laws)}")
    return keys


def _label(database: Database) -> str:
    return str(getattr(database, "name", "") or database.path)


def _naming_database(err: DatabaseError, database: Database) -> DatabaseError:
    """The error with the database's name in front (the inverters see its rows, not its file),
    unless it names it already."""
    name, path = str(getattr(database, "name", "")), str(database.path)
    label = f"{name} ({path})" if name and name != path else path
    return err if path in str(err) else DatabaseError(f"{label}: {err}")


def _capsules(capsules: CapsulesLike, flow: str) -> list[Capsule]:
    """The capsules of a measurement file, a DataFrame (``capsmech.io.measurement_frames``)
    or a sequence of ``Capsule``; anything else is a ``MeasurementError`` saying what is taken."""
    if isinstance(capsules, (str, Path)):
        return read_measurements(capsules, flow)
    if isinstance(capsules, pd.DataFrame):
        return capsules_from_frame(capsules, flow)
    items = list(capsules) if isinstance(capsules, Iterable) else None
    if items is None or not all(isinstance(item, Capsule) for item in items):
        raise MeasurementError(f"measurements: a file path, a pandas DataFrame or a list of Capsule, not "
                               f"{type(capsules).__name__}")
    return items


#: A database's channel in words, with the length its lengths are in.
CHANNEL_WORDS = {"tube": "a circular tube (lengths in its radius)",
                 "square": "a square channel (lengths in its half-width)",
                 "rect": "a rectangular channel (lengths in its half-width)"}
#: The measurement column that gives each channel's length scale.
CHANNEL_COLUMN = {"tube": "tube_radius", "square": "half_width"}
#: A channel as an adjective, and the channel with its article.
_CHANNEL_KIND = {"tube": "circular-tube", "square": "square-channel", "rect": "rectangular-channel"}
_CHANNEL_NOUN = {"tube": "a circular tube", "square": "a square channel", "rect": "a rectangular channel"}


def check_channel(capsules: Sequence[Capsule], database: Database, source: str) -> None:
    """Refuse capsules measured in another channel than the one ``database`` was computed for:
    its lengths are in that channel's length scale (``Capsule.channel``, ``Database.channel``).

    Raises
    ------
    MeasurementError
        Naming the measurements' column, the database and what to do.
    """
    channel = database.channel
    measured = {capsule.channel for capsule in capsules}
    if channel not in CHANNEL_COLUMN or database.aspect != 1.0:
        raise MeasurementError(f"{source}: {_label(database)} is a database of channel {channel!r}, aspect "
                               f"{database.aspect:g}; capsules are fitted in circular tubes (tube_radius) and square "
                               "channels (half_width) only")
    other = measured - {channel}
    if other:
        given = other.pop()
        raise MeasurementError(f"{source}: the capsules were measured in {_CHANNEL_NOUN[given]} (column "
                               f"{CHANNEL_COLUMN[given]}), but {_label(database)} is a {_CHANNEL_KIND[channel]} database: "
                               f"fit them against a {_CHANNEL_KIND[given]} database, or give {CHANNEL_COLUMN[channel]} "
                               f"if they flowed in {_CHANNEL_NOUN[channel]}")


def channel_of(capsules: Sequence[Capsule], database: Database) -> dict[str, Any]:
    """The channel the fit was made in, as the results state it: ``channel``, its ``aspect``
    (height over width) and each capsule's ``length_scale`` [m] (id -> l: the tube's radius or
    the channel's half-width)."""
    return {"channel": database.channel, "channel_aspect": database.aspect,
            "length_scale": {capsule.id: capsule.length_scale for capsule in capsules}}


#: The columns that state the channel in fit-tube's written results (``with_channel_columns``).
CHANNEL_RESULT_UNITS = {"channel": "", "channel_aspect": "1", "length_scale": "m"}


def with_channel_columns(results: pd.DataFrame) -> pd.DataFrame:
    """``fit_tube``'s results with the channel stated in every row, as ``capsmech fit-tube``
    writes them: ``channel``, ``channel_aspect`` and the capsule's ``length_scale`` [m] after
    ``law`` (from ``attrs["channel"]``; the results unchanged without it)."""
    channel = results.attrs.get("channel")
    if channel is None:
        return results
    out = results.copy()
    at = list(out.columns).index("law") + 1 if "law" in out.columns else len(out.columns)
    out.insert(at, "length_scale", [channel["length_scale"].get(i, math.nan) for i in out["id"]])
    out.insert(at, "channel_aspect", float(channel["channel_aspect"]))
    out.insert(at, "channel", str(channel["channel"]))
    out.attrs["units"] = _channel_units(results.attrs.get("units", {}))
    return out


def _channel_units(units: Mapping[str, str]) -> dict[str, str]:
    """Results' units with ``CHANNEL_RESULT_UNITS`` after ``law``'s."""
    names = list(units)
    cut = names.index("law") + 1 if "law" in names else len(names)
    return {**{n: units[n] for n in names[:cut]}, **CHANNEL_RESULT_UNITS, **{n: units[n] for n in names[cut:]}}


def _source(capsules: CapsulesLike) -> str:
    """The measurements' name in a message: the file, or 'measurements'."""
    return str(capsules) if isinstance(capsules, (str, Path)) else "measurements"


def _frame(rows: Sequence[Mapping[str, Any]], units: Mapping[str, str]) -> pd.DataFrame:
    frame = pd.DataFrame(list(rows), columns=list(units))
    frame.attrs["units"] = dict(units)
    return frame


def _warn_unfitted(frame: pd.DataFrame, database: Database) -> None:
    """One warning that says how many (capsule, law) rows have no value and why, by flag code."""
    flagged = frame[frame["flag"] != ""]
    if flagged.empty:
        return
    counts = flagged["flag"].value_counts()
    warnings.warn(f"{len(flagged)} of {len(frame)} (capsule, law) fits have no value against {_label(database)}: "
                  + ", ".join(f"{n} {code}" for code, n in counts.items()) + " (see the 'reason' column)",
                  OutsideDatabaseWarning, stacklevel=3)


def _warn_implausible_modulus(frame: pd.DataFrame) -> None:
    """One warning when the batch's fitted G_s lies outside the range of real membranes: a unit slip."""
    fitted = frame.loc[frame["flag"] == "", "G_s"].to_numpy(dtype=float)
    fitted = fitted[np.isfinite(fitted)]
    if fitted.size == 0:
        return
    sentence = plausibility.out_of_range("the fitted G_s", plausibility.SHEAR_MODULUS, [float(np.median(fitted))],
                                         f"median of {fitted.size} fits")
    if sentence:
        warnings.warn(sentence, InputWarning, stacklevel=3)


def fit_tube(capsules: CapsulesLike, database: DatabaseLike = "tube-paper", laws: str | Iterable[str] | None = None,
             progress: bool = False) -> pd.DataFrame:
    """Fit capsules measured in a tube (capillary) with every law asked for (paper section 4.2).

    Parameters
    ----------
    capsules : DataFrame, str or Path, or sequence of Capsule
        Measured capsules: a measurement file (CSV or ``.xlsx``), a DataFrame with units in
        its column names or ``attrs["units"]`` (``pd.read_csv`` of such a file,
        ``capsmech.io.measurement_frames.read_batch``), or capsules (``capsmech.io.measurements``).
    database : Database, str or Path
        A tube database, its shipped name (default ``"tube-paper"``) or its file.
    laws : str or iterable of str, optional
        Law keys (``"NH"``, ``["NH", "GH_nu0.5"]``); default every law of the database.
    progress : bool
        Show a progress bar on stderr.

    Returns
    -------
    DataFrame
        One row per (capsule, law): a/l, Ca_s, v_c/V and G_s [N/m] with their spreads, Delta,
        H/a, residuals, the law's critical Ca_s at the fitted a/l and the fitted Ca_s over it
        (where the database records its folds: ``Database.critical``; a fit above it is flagged
        ``above_fold``), ``flag`` (code, empty when fitted) and ``reason``; units in
        ``attrs["units"]``; the channel in ``attrs["channel"]`` (``channel_of``: l is the tube's
        radius, or a square channel's half-width). Rows without a value raise one
        ``OutsideDatabaseWarning``.

    Raises
    ------
    MeasurementError
        Also when the capsules were measured in another channel than the database's
        (``tube_radius``: a circular tube; ``half_width``: a square channel).
    """
    db = as_database(database, "tube", "fit_tube")
    keys = check_laws(db, laws)
    measured = _capsules(capsules, "tube")
    check_channel(measured, db, _source(capsules))
    try:
        rows = fit_tube_rows(measured, db, keys, progress=progress)
    except DatabaseError as err:
        raise _naming_database(err, db) from None
    add_fold_columns(rows, db)
    frame = _frame(rows, TUBE_RESULT_UNITS)
    frame.attrs["channel"] = channel_of(measured, db)
    _warn_unfitted(frame, db)
    _warn_implausible_modulus(frame)
    return frame


def fit_shear(capsules: CapsulesLike, database: DatabaseLike = "shear-paper",
              laws: str | Iterable[str] | None = None) -> pd.DataFrame:
    """Fit capsules sheared in a Couette rheometer from their deformation D12 (paper section 4.3).

    Parameters and result as ``fit_tube`` (columns D12, Ca_s, L3/a, a [m], G_s [N/m], flag, reason).
    """
    db = as_database(database, "shear", "fit_shear")
    keys = check_laws(db, laws)
    measured = _capsules(capsules, "shear")
    try:
        rows = fit_shear_rows(measured, db, keys)
    except DatabaseError as err:
        raise _naming_database(err, db) from None
    frame = _frame(rows, SHEAR_RESULT_UNITS)
    _warn_unfitted(frame, db)
    _warn_implausible_modulus(frame)
    return frame


def read_results(path: str | Path) -> pd.DataFrame:
    """A results file written by ``capsmech fit-tube``, ``fit-shear`` or ``population`` with
    ``--out``: a CSV with ``name [unit]`` headers or an HDF5 file (told apart by its first
    bytes); the units in ``attrs["units"]``, the columns in the order the command writes them.

    Raises
    ------
    capsmech.io.results.ResultsFileError
        A file that is not such a table (naming the file, and the line or dataset, and field).
    """
    from capsmech.inversion.population_report import POPULATION_UNITS
    from capsmech.io.results import read_results_table

    rows, units = read_results_table(path, required=())
    for known in (TUBE_RESULT_UNITS, _channel_units(TUBE_RESULT_UNITS), SHEAR_RESULT_UNITS, POPULATION_UNITS):
        # An HDF5 file without its column order lists the columns by name: the command's order back.
        if set(units) == set(known):
            units = {name: units[name] for name in known}
    frame = pd.DataFrame(rows, columns=list(units))
    frame.attrs["units"] = units
    for column, unit in units.items():
        # A column with a unit holds numbers (checked by the reader; an empty cell: NaN), parsed
        # by float() so that every digit an HDF5 file holds comes back; one without is text.
        frame[column] = (np.array([float(v) if str(v).strip() else math.nan for v in frame[column]], dtype=float)
                         if unit else frame[column].fillna(""))
    return frame


def _result_rows(results: ResultsLike | Sequence[str | Path]) -> list[dict[str, Any]]:
    if isinstance(results, (str, Path)):
        results = [results]
    if isinstance(results, pd.DataFrame):
        return _records(results)
    items = list(results)
    if items and isinstance(items[0], (str, Path)):
        # Results files (the first says it of all).
        return [row for path in cast("list[str | Path]", items) for row in _records(read_results(path))]
    return [dict(row) for row in cast("list[Mapping[str, Any]]", items)]


def _records(frame: pd.DataFrame) -> list[dict[str, Any]]:
    # pandas types the keys as Hashable; the columns of capsmech's frames are str.
    return cast("list[dict[str, Any]]", frame.to_dict("records"))


def population(results: ResultsLike | Sequence[str | Path]) -> PopulationVerdict:
    """Which membrane law describes the batch (paper section 4.4, over every measured capsule).

    Parameters
    ----------
    results : DataFrame, rows, or results file(s)
        ``fit_tube`` results with several laws (columns id, law, Delta, G_s, H_over_a, flag).

    Returns
    -------
    PopulationVerdict
        ``kind`` ('law', 'not_one_material', 'cannot_tell' or 'none'), ``best`` (the law, or None),
        ``candidates`` (the laws not told apart), ``reason``, ``g_s`` and ``g_s_interval`` [N/m], the
        ``evidence`` per law (capsules fitted, median contour score, p-value against the
        reference law, G_s, drift), the capsules ``left_out`` and why;
        ``population_table(verdict)`` gives the evidence as a DataFrame and
        ``capsmech.inversion.population_report.verdict_dict`` as JSON-ready data.
    """
    return population_verdict(_result_rows(results))


def fits_above_fold(results: ResultsLike | Sequence[str | Path]) -> dict[str, list[str]]:
    """Per law, the capsules fit-tube fitted above the law's fold (flag ``above_fold``: no steady
    shape of the law there, so the law cannot hold them steady); laws without any are left out."""
    above: dict[str, list[str]] = {}
    for row in _result_rows(results):
        if str(row.get("flag") or "") == "above_fold":
            above.setdefault(str(row["law"]), []).append(str(row["id"]))
    return above


def population_table(verdict: PopulationVerdict) -> pd.DataFrame:
    """The evidence per law, best ranked first: capsules fitted of those used, median contour
    score, p-value against the reference law, mean G_s [N/m] with its spread and 95 % interval,
    drift per unit Delta with its 95 % interval and p-value, and the law's status ('verdict',
    'candidate', 'fits < half', 'drifts', 'misfits noise', 'worse contours', 'no verdict')."""
    from capsmech.inversion.population_report import POPULATION_UNITS, population_rows

    return _frame(population_rows(verdict), POPULATION_UNITS)


def plot_population(results: ResultsLike | Sequence[str | Path], verdict: PopulationVerdict | None = None) -> Figure:
    """G_s against the profile elongation Delta per law, with each law's drift (paper figure 10)."""
    rows = _result_rows(results)
    verdict = verdict or population_verdict(rows)
    return plot_population_rows(rows, verdict.drifts, verdict.estimator)


#: Levels of the scalar effect candidates when not given (those of the shipped effect databases).
DEFAULT_PRESTRESS_LEVELS = (0.04, 0.06, 0.08)
DEFAULT_KB_LEVELS = (0.0025, 0.005, 0.01)
CANDIDATE_NAMES = ("contour_offset", "tube_radius", "prestress", "kb", "SK_C", "GH_nu", "laws")


def diagnose(capsules: CapsulesLike, database: DatabaseLike = "tube-paper", law: str = "NH", *,
             effect_databases: Sequence[DatabaseLike] | None = None, other_laws: Sequence[str] | None = None,
             prestress_levels: Sequence[float] = DEFAULT_PRESTRESS_LEVELS,
             kb_levels: Sequence[float] = DEFAULT_KB_LEVELS,
             family_levels: Mapping[str, Sequence[float]] | None = None, candidates: Sequence[str] | None = None,
             max_effects: int = 2, offcentre_table: OffcentreTable | str | Path | None = "offcentre",
             progress: bool = False) -> SequentialDiagnosis | Diagnosis:
    """Which effect the base model lacks, from what the fits of a tube batch leave (closing the loop).

    Parameters
    ----------
    capsules : DataFrame, str or Path, or sequence of Capsule
        A tube batch with contours, as ``fit_tube`` takes it.
    database : Database, str or Path
        The base tube database (default ``"tube-paper"``).
    law : str
        The base law key.
    effect_databases : sequence, optional
        Tube databases of effect law groups; default the shipped ones (pre-stress, bending).
    other_laws : sequence of str, optional
        Law groups to test as candidates (default every other law of the database).
    prestress_levels, kb_levels : sequence of float
        Levels of the pre-stress and bending candidates (empty: no such candidate).
    family_levels : mapping, optional
        Levels of the continuous law parameters, e.g. ``{"SK_C": [1, 2, 4, 8]}`` (an empty list: no
        such candidate). Levels no database holds make the candidate "needs simulations". A
        family not given is tried over the levels of ``LAW_FAMILIES`` that the databases hold
        (GH's nu_s over 0, 0.2 and 0.5 with the shipped ones), if at least two.
    candidates : sequence of str, optional
        Test only these (``CANDIDATE_NAMES``).
    max_effects : int
        Effects to look for one after another (1: a single round, a ``Diagnosis``).
    offcentre_table : OffcentreTable, name, path or None
        Modes to fit the offset of capsules screened out as asymmetric (None: leave them unfitted).
    progress : bool
        Progress bars on stderr (a diagnosis refits the batch hundreds of times: minutes).

    Returns
    -------
    SequentialDiagnosis or Diagnosis
        The rounds, the effects found and G_s before and after (``.verdict`` says it in words).
    """
    from capsmech.diagnosis.candidates import DatabaseSet, candidate_library
    from capsmech.diagnosis.diagnose import diagnose as diagnose_round
    from capsmech.diagnosis.law_family import LAW_FAMILIES, family_member, law_family_candidates
    from capsmech.diagnosis.sequential import diagnose_sequential

    base = as_database(database, "tube", "diagnose")
    if effect_databases is None:
        from capsmech.io.catalog import effect_database_paths

        # The shipped effect databases are circular tubes'.
        effect_databases = list(effect_database_paths()) if base.channel == "tube" else []
    effects = [as_database(d, "tube", "diagnose (effect database)") for d in effect_databases]
    for effect in effects:
        if (effect.channel, effect.aspect) != (base.channel, base.aspect):
            raise DatabaseError(f"diagnose: effect database {_label(effect)} is of {CHANNEL_WORDS.get(effect.channel)}, "
                                f"the base {_label(base)} of {CHANNEL_WORDS.get(base.channel)}")
    databases = DatabaseSet([base, *effects])
    check_laws(base, [law], "law")
    for key in other_laws or []:
        if key not in databases.laws:
            raise DatabaseError(f"other law: no law {key!r} in the base or effect databases; valid laws: "
                                f"{', '.join(databases.laws)}")
    for name, levels in (("prestress_levels", prestress_levels), ("kb_levels", kb_levels)):
        if any(not (math.isfinite(v) and v > 0) for v in levels):
            raise DatabaseError(f"{name}: levels must be finite and > 0 (0 is the base law): {list(levels)}")
    unknown = [c for c in candidates or [] if c not in CANDIDATE_NAMES]
    if unknown:
        raise DatabaseError(f"candidates: unknown {', '.join(unknown)}; valid: {', '.join(CANDIDATE_NAMES)}")
    if max_effects < 1:
        raise DatabaseError(f"max_effects: must be at least 1, got {max_effects}")
    table = _offcentre(offcentre_table)
    unknown = [f for f in family_levels or {} if f not in LAW_FAMILIES]
    if unknown:
        raise DatabaseError(f"family_levels: unknown law family {', '.join(unknown)}; valid: {', '.join(LAW_FAMILIES)}")
    for family, values in (family_levels or {}).items():
        if len(values) == 1 or any(not math.isfinite(v) for v in values):
            raise DatabaseError(f"family_levels: {family} needs at least two finite levels (none: no candidate), "
                                f"got {list(values)}")
    family_levels_here = _family_levels(family_levels, databases.laws)

    def library(base_law: Any) -> list:
        found = candidate_library(base_law, list(base.laws), list(prestress_levels), other_laws,
                                  kb_levels=list(kb_levels))
        families = [c for c in law_family_candidates(base_law, family_levels_here)
                    if not candidates or c.name in candidates]
        if other_laws is None:
            # A family at one of its levels is that law group: its yes/no candidate would only
            # tie with the family (named by the user with --other-law, it stays).
            covered = {c.name for c in families}
            found = [c for c in found if not (c.name.startswith("law ") and (member := family_member(c.name[4:]))
                                              and member[0] in covered)]
        found += families
        if candidates:
            found = [c for c in found if c.name in candidates or ("laws" in candidates and c.name.startswith("law "))]
        return found

    batch = _capsules(capsules, "tube")
    check_channel(batch, base, _source(capsules))
    if max_effects == 1:
        return diagnose_round(batch, databases, law, library(law), offcentre_table=table, progress=progress)
    names = {c.name for c in library(law)}
    return diagnose_sequential(batch, databases, law, lambda current: [c for c in library(current) if c.name in names],
                               max_effects=max_effects, offcentre_table=table, progress=progress)


def _family_levels(given: Mapping[str, Sequence[float]] | None, laws: Sequence[str]) -> dict[str, list[float]]:
    """The levels of each law family's candidate: those given, else the family's default levels
    the databases hold (GH's nu_s: 0, 0.2, 0.5 in the paper grid; Skalak's C: 1 only, so no
    candidate: no simulations unless asked for)."""
    from capsmech.diagnosis.law_family import LAW_FAMILIES, family_key

    out = {}
    for family, (_, defaults) in LAW_FAMILIES.items():
        if given is not None and family in given:
            out[family] = [float(v) for v in given[family]]
        else:
            held = [float(v) for v in defaults if family_key(family, v) in laws]
            out[family] = held if len(held) >= 2 else []
    return out


def _offcentre(table: OffcentreTable | str | Path | None) -> OffcentreTable | None:
    from capsmech.diagnosis.offcentre import OffcentreError, OffcentreTable

    if table is None or isinstance(table, OffcentreTable):
        return table
    if str(table) == "offcentre":
        from capsmech.io.catalog import offcentre_table_path

        table = offcentre_table_path()
    try:
        return OffcentreTable.read(table)
    except OffcentreError as err:
        raise DatabaseError(f"offcentre_table: {err}") from None


@dataclass
class Extraction:
    """What ``extract`` found in a stack of frames.

    Attributes
    ----------
    capsules : DataFrame
        One row per capsule passage: ``id``, ``good_frames``, ``frames``, ``L_z``, ``L_p``
        [um] with their spreads over the good frames, ``v_c`` [mm/s] with its standard error,
        ``tube_radius`` [um] with its standard uncertainty ``tube_radius_sigma`` (NaN: walls
        given; in a square channel ``half_width`` and ``half_width_sigma``), ``flag`` (``""`` measured, ``too_few_frames``, ``not_moving``,
        ``not_steady``) and ``reason`` (for a measured independent event: why it has no
        velocity); units in ``attrs["units"]``.
    frames : DataFrame
        One row per frame: index, label, passage (-1: none), flag (empty: measured) and the
        frame's lengths [px].
    pixel_size_um, frame_rate : float
        The calibration used [um per pixel, frames per second].
    walls, stack, results, measurements
        The walls found, the frames and the per-frame and per-capsule objects (what the
        writers of ``capsmech.imaging.extraction_output`` take).
    channel : capsmech.imaging.extraction.Channel
        The stack's geometry: tilt removed, background used, walls and the check of the
        channel width given against the one found (``channel.width_check``).
    """

    capsules: pd.DataFrame
    frames: pd.DataFrame
    pixel_size_um: float
    frame_rate: float
    walls: Any
    stack: Any
    results: list[Any]
    measurements: list[Any]
    channel: Any = None
    channel_shape: str = "tube"


#: Columns of ``Extraction.capsules`` and their units (lengths as the measurement CSV has them).
EXTRACTION_UNITS = {"id": "", "good_frames": "1", "frames": "1", "L_z": "um", "L_z_spread": "um", "L_p": "um",
                    "L_p_spread": "um", "v_c": "mm/s", "v_c_se": "mm/s", "tube_radius": "um", "tube_radius_sigma": "um",
                    "contour_noise": "um",
                    "flag": "", "reason": ""}


def _quantity(value: float | str | None, name: str, units: dict[str, float], default_unit: str) -> float | None:
    from capsmech.imaging.extraction_output import parse_quantity

    if value is None or isinstance(value, (int, float)):
        return None if value is None else float(value)
    return parse_quantity(value, name, units, default_unit)


def extract(frames: str | Path | Sequence[str | Path], pixel_size: float | str | None = None,
            frame_rate: float | str | None = None, *, flow_direction: str = "auto", capsule_id: str | None = None,
            max_asymmetry: float = 0.05, max_line_width: float = 10.0, min_frames: int = 3,
            progress: bool = False, background: str | Path | Any | None = None,
            walls: str | tuple[float, float] | None = None, channel_width: float | str | None = None,
            frame_times: str | Path | Any | None = None, tilt: float | None = None,
            channel_width_tolerance: float = 0.02, channel_shape: str = "tube") -> Extraction:
    """Measure the capsules of a stack of frames of a tube: lengths, velocity, contours.

    Parameters
    ----------
    frames : path, glob pattern or sequence of them
        A multi-page TIFF, image files or folders in frame order, an ``.rtdc`` recording or a
        video (AVI, MP4, MKV, ...).
    pixel_size : float or str, optional
        One pixel [um], or a quantity with its unit (``"0.5um"``); default the file's metadata
        (TIFF resolution, ``.rtdc`` ``imaging:pixel size``).
    frame_rate : float or str, optional
        Frames per second (``1000``, ``"1kHz"``); default the file's (TIFF frame interval,
        ``.rtdc`` ``imaging:frame rate``, the video's rate). Frame numbers the file gives (an
        ``.rtdc``'s camera frames, a video's presentation times) are kept: gaps stay gaps.
    flow_direction : {"auto", "right", "left"}
        The flow's direction in the images: "auto" (default) finds it from the objects' motion
        between consecutive frames (frames moving in -x are mirrored; +x assumed when no object
        is followed, said in ``Extraction.channel.flow_check``); "left" mirrors the frames first;
        a given direction is checked against the motion.
    capsule_id : str, optional
        Id of the capsule (several: ``ID-1``, ``ID-2``, ...); default the first file's name.
    max_asymmetry, max_line_width, min_frames
        A frame is flagged when its halves differ by more than ``max_asymmetry`` of L_z/2 or
        its line is wider than ``max_line_width`` [px]; a capsule needs ``min_frames`` good ones.
    progress : bool
        A progress bar on stderr.
    background : path or 2-D array, optional
        The empty channel as recorded (same size and orientation as the frames); default: the
        temporal median of the stack (its per-row median for stacks under 5 frames).
    walls : "ROW1,ROW2" or (row1, row2), optional
        The walls' rows (px, at the image's centre column), instead of detecting them.
    channel_width : float or str, optional
        The channel's width [um] (``"20um"``): checked against the walls found (the difference
        is in ``Extraction.channel.width_check``), and used to place a wall outside the view.
    frame_times : path or sequence of float, optional
        Each frame's time [s] (a CSV with a ``time_s`` column, optionally ``page``): gaps
        between frames are honoured (new passage, velocity from the times).
    tilt : float, optional
        The channel's tilt [deg] when known; default: estimated from the walls.
    channel_width_tolerance : float
        The tolerance of ``channel_width``, a fraction of it (default 0.02): a width found
        that differs by more than it plus twice its own uncertainty is a disagreement
        (``Extraction.channel.width_disagrees``).
    channel_shape : {"tube", "square"}
        What the walls bound: a circular tube (default; their half distance is its radius,
        ``tube_radius``) or a square channel seen through a face (its half-width,
        ``half_width``: the length scale of a square-channel database, which ``fit_tube`` checks).

    Returns
    -------
    Extraction
        ``capsules`` and ``frames`` as DataFrames, and what the writers need.

    Raises
    ------
    ExtractionError
        Unreadable frames, no walls, or no calibration in the files or the arguments.
    """
    import numpy as np
    from tqdm import tqdm

    from capsmech.imaging.channel import parse_walls
    from capsmech.imaging.extraction import (
        ExtractionError,
        ExtractionSettings,
        extract_stack,
        measure_capsules,
        read_frame_times,
        read_frames,
    )
    from capsmech.imaging.extraction_output import PIXEL_UNITS_UM, RATE_UNITS_HZ, check_id, default_ids
    from capsmech.io.measurement_columns import CHANNEL_SHAPES, length_scale_columns

    if channel_shape not in CHANNEL_SHAPES:
        raise ExtractionError(f"channel_shape: {channel_shape!r} is none of {', '.join(CHANNEL_SHAPES)}")
    scale, scale_sigma = length_scale_columns(channel_shape)
    paths = [frames] if isinstance(frames, (str, Path)) else list(frames)
    pixel_um = _quantity(pixel_size, "pixel_size", PIXEL_UNITS_UM, "um")
    rate = _quantity(frame_rate, "frame_rate", RATE_UNITS_HZ, "Hz")
    settings = ExtractionSettings(max_asymmetry=max_asymmetry, max_line_width_px=max_line_width,
                                  min_good_frames=min_frames)
    stack = read_frames(paths, flow_direction)
    pixel_um = pixel_um or stack.pixel_size_um
    rate = rate or stack.frame_rate
    if pixel_um is None:
        raise ExtractionError("pixel_size: required (the files carry no pixel size)")
    if frame_times is not None:
        if isinstance(frame_times, (str, Path)):
            stack.times_s = read_frame_times(frame_times, len(stack))
        else:
            stack.times_s = np.asarray(frame_times, dtype=float)
            if stack.times_s.shape != (len(stack),) or np.any(np.diff(stack.times_s) <= 0):
                raise ExtractionError(f"frame_times: need {len(stack)} increasing times, one per frame")
        if rate is None and len(stack) > 1:
            rate = 1.0 / float(np.median(np.diff(stack.times_s)))
    if rate is None:
        raise ExtractionError("frame_rate: required (the files carry no frame interval)")
    bg = None
    if background is not None:
        if isinstance(background, (str, Path)):
            bg = read_frames([background], flow_direction).frames[0]
        else:
            bg = np.asarray(background, dtype=np.float32)
            bg = bg[:, ::-1] if flow_direction == "left" else bg
    wall_rows = parse_walls(walls) if isinstance(walls, str) else walls
    width_um = _quantity(channel_width, "channel_width", PIXEL_UNITS_UM, "um")
    bar = tqdm(total=len(stack), desc="frames", unit="frame", disable=not progress, leave=False)

    def advance(done: int, total: int) -> None:
        bar.update(done - bar.n)

    channel, results = extract_stack(stack, settings, advance, wall_rows, bg,
                                     width_um / pixel_um if width_um else None, tilt, rate,
                                     channel_width_tolerance=channel_width_tolerance)
    bar.close()
    measurements = measure_capsules(results, rate, settings, independent_events=bool(channel.independent_events))
    ids = default_ids(check_id(capsule_id) if capsule_id else Path(stack.labels[0].split("[")[0]).stem,
                      len(measurements))
    rows = []
    for cap_id, cap in zip(ids, measurements):
        flag = "" if cap.ok else ("too_few_frames" if "good frame" in cap.problem else
                                  "not_steady" if cap.problem.startswith("not steady") else "not_moving")
        rows.append({"id": cap_id, "good_frames": len(cap.good_frames), "frames": len(cap.frames),
                     "L_z": cap.L_z_px * pixel_um, "L_z_spread": cap.L_z_spread_px * pixel_um,
                     "L_p": cap.L_p_px * pixel_um, "L_p_spread": cap.L_p_spread_px * pixel_um,
                     "v_c": cap.v_c_px_s * pixel_um * 1e-3, "v_c_se": cap.v_c_se_px_s * pixel_um * 1e-3,
                     scale: channel.walls.radius_px * pixel_um,
                     scale_sigma: channel.walls.radius_sigma_px * pixel_um,
                     "contour_noise": cap.contour_noise_px * pixel_um, "flag": flag,
                     "reason": cap.problem or cap.note})
    frame_rows = [{"index": r.index, "label": r.label, "time_s": r.time_s, "passage": r.passage, "flag": r.flag,
                   "objects": r.objects, "kind": r.kind, "contour_at": r.contour_at, "extent_px": r.extent_px,
                   "outer_extent_px": r.outer_extent_px, "L_z_px": r.L_z_px, "L_p_px": r.L_p_px,
                   "centroid_x_px": r.centroid_x, "asymmetry": r.asymmetry} for r in results]
    # The tube's columns named as the channel's (the same place, the same unit).
    renamed = {"tube_radius": scale, "tube_radius_sigma": scale_sigma}
    units = {renamed.get(name, name): unit for name, unit in EXTRACTION_UNITS.items()}
    return Extraction(_frame(rows, units), pd.DataFrame(frame_rows), float(pixel_um), float(rate),
                      channel.walls, stack, results, measurements, channel, channel_shape)


def extract_shear(frames: str | Path | Sequence[str | Path], pixel_size: float | str | None = None, *,
                  one_capsule: bool = False, capsule_id: str | None = None, line: str = "dark",
                  flow_angle: float = 0.0, min_radius: float = 6.0, background: str | Path | Any | None = None,
                  progress: bool = False) -> ShearExtraction:
    """Measure capsules in the shear plane of a Couette rheometer: outline -> ellipse (paper §4.3).

    Parameters
    ----------
    frames : path, glob pattern or sequence of them
        Image files, multi-page TIFFs or folders (as ``extract`` reads them).
    pixel_size : float or str, optional
        One pixel [um], or a quantity with its unit (``"1.4um"``); default the files' metadata.
    one_capsule : bool
        The frames show one capsule: its frames are combined into one row. Default: every
        capsule of every frame is a row of its own.
    capsule_id : str, optional
        Id (several capsules: ``ID-1``, ``ID-2``, ...); default the first file's name.
    line : {"dark", "bright"}
        The membrane's ring is darker (bright field) or brighter than the liquid.
    flow_angle : float
        The flow's direction on the screen [deg], counter-clockwise from the image's +x axis.
    min_radius : float
        Smaller objects [px, equivalent radius] are specks.
    background : path or 2-D array, optional
        An image of the empty field; default a smooth surface fitted to each frame.
    progress : bool
        A progress bar on stderr.

    Returns
    -------
    capsmech.imaging.shear_plane.ShearExtraction
        ``capsule_rows()`` (L1, L2 [um], D12, theta [deg], each with its uncertainty at two
        standard deviations), ``objects`` (every object found, measured or with its reason) and
        ``measurements(shear_rate, mu)``: the capsules as ``fit_shear`` takes them.

    Raises
    ------
    ExtractionError
        Unreadable frames, bad options, or no pixel size in the files or the arguments.
    """
    import numpy as np
    from tqdm import tqdm

    from capsmech.errors import ExtractionError
    from capsmech.imaging.extraction_output import PIXEL_UNITS_UM, check_id, default_ids
    from capsmech.imaging.frames import read_frames
    from capsmech.imaging.shear_plane import ShearSettings, measure_stack

    paths = [frames] if isinstance(frames, (str, Path)) else list(frames)
    settings = ShearSettings(line=line, flow_angle_deg=float(flow_angle), min_radius_px=float(min_radius))
    stack = read_frames(paths)
    pixel_um = _quantity(pixel_size, "pixel_size", PIXEL_UNITS_UM, "um") or stack.pixel_size_um
    if pixel_um is None:
        raise ExtractionError("pixel_size: required (the files carry no pixel size)")
    bg = None
    if background is not None:
        bg = (read_frames([background]).frames[0] if isinstance(background, (str, Path))
              else np.asarray(background, dtype=float))
    bar = tqdm(total=len(stack), desc="frames", unit="frame", disable=not progress, leave=False)

    def advance(done: int, total: int) -> None:
        bar.update(done - bar.n)

    try:
        return measure_stack(stack.frames, stack.labels, float(pixel_um), settings,
                             stem=check_id(capsule_id) if capsule_id else default_ids(
                                 Path(stack.labels[0].split("[")[0]).stem, 1)[0], one_capsule=one_capsule,
                             background=bg, progress=advance)
    finally:
        bar.close()


def diagnose_shear(capsules: CapsulesLike, database: DatabaseLike = "shear-paper",
                   lambda_database: DatabaseLike = "shear-microrheometry", law: str = "NH", *,
                   lambda_value: str | None = None, pixel_size: float | None = None, error_px: float | None = None,
                   theta_error: float | None = None) -> ShearDiagnosis:
    """Which effect (the experiment's viscosity ratio, another law) a Couette batch's G_s drift
    supports (``capsmech.diagnosis.shear``).

    Parameters
    ----------
    capsules : sequence of Capsule, or str or Path
        A shear batch (at least 3 capsules).
    database : Database, str or Path
        The shear database made with viscosity ratio 1 (default ``"shear-paper"``).
    lambda_database : Database, str or Path
        The shear database at the candidate viscosity ratio (law keys ``<law>+lambda<X>``).
    law : str
        The base law key.
    lambda_value : str, optional
        That viscosity ratio as the law keys spell it (default ``diagnosis.shear.LAMBDA_VALUE``).
    pixel_size : float, optional
        The noise model's pixel [m] where the batch has no ``pixel_size`` column.
    error_px : float, optional
        Error bound of each semi-axis [px].
    theta_error : float, optional
        Standard deviation of a measured inclination [rad].

    Returns
    -------
    ShearDiagnosis
        Every candidate's criteria, the chosen one and ``verdict`` in words.

    Raises
    ------
    DatabaseError
        A database of another flow, or a law key it does not hold.
    MeasurementError
        Fewer than 3 capsules, or a noise parameter that is not a positive number.
    """
    from capsmech.diagnosis import shear
    from capsmech.io.measurements import MeasurementError

    lambda_value = shear.LAMBDA_VALUE if lambda_value is None else lambda_value
    noise = {"pixel_size": shear.PIXEL_SIZE if pixel_size is None else pixel_size,
             "error_px": shear.ERROR_PX if error_px is None else error_px,
             "theta_error": shear.THETA_ERROR if theta_error is None else theta_error}
    for name, value in noise.items():
        if not (math.isfinite(value) and value > 0):
            raise MeasurementError(f"{name}: must be a positive number, got {value}")
    databases = [as_database(database, "shear", "diagnose_shear (database)"),
                 as_database(lambda_database, "shear", "diagnose_shear (lambda_database)")]
    check_laws(databases[0], [law], "law")
    key = shear.lambda_key(law, lambda_value)
    if key not in databases[1].laws:
        raise DatabaseError(f"lambda_value: {_label(databases[1])} has no law {key!r} "
                            f"(it has {', '.join(databases[1].laws)})")
    batch = _capsules(capsules, "shear")
    candidates = shear.default_candidates(law, databases[0].laws, lambda_value)
    try:
        return shear.diagnose_shear(batch, shear.ShearGroups(databases), law, candidates, **noise)
    except ValueError as err:
        if isinstance(err, CapsmechError):
            raise
        raise MeasurementError(f"{capsules if isinstance(capsules, (str, Path)) else 'capsules'}: {err}") from None


def make_batch(effects: Mapping[str, float] | None = None, n_capsules: int = 24, law: str = "NH",
               g_s: float = 0.04, *, seed: int = 0, workers: int = 1) -> Batch:
    """A synthetic tube batch with undeclared effects, simulated with the kernel, to check
    ``diagnose`` on (``capsmech.diagnosis.undeclared_tube``).

    Parameters
    ----------
    effects : mapping, optional
        Effect name -> strength (``{"prestress": 0.06}``); none by default.
    n_capsules : int
        Capsules drawn (those that reach no steady state are left out).
    law : str
        The base law the batch will be fitted with.
    g_s : float
        The membrane's G_s [N/m].
    seed : int
        Random seed of the draw and the noise.
    workers : int
        Kernel runs at a time.

    Returns
    -------
    capsmech.diagnosis.undeclared_tube.Batch
        The measurement rows and the truth (``write_batch`` writes both).

    Raises
    ------
    MeasurementError
        An unknown effect, two laws at once, or a value out of range (the message says which).
    """
    from capsmech.diagnosis.undeclared_tube import make_batch as simulate_batch
    from capsmech.io.measurements import MeasurementError

    try:
        return simulate_batch(dict(effects or {}), n_capsules=n_capsules, law=law, g_s=g_s, seed=seed,
                              workers=workers)
    except ValueError as err:
        if isinstance(err, CapsmechError):
            raise
        raise MeasurementError(str(err)) from None


def write_batch(batch: Batch, path: str | Path) -> tuple[Path, Path]:
    """Write a ``make_batch`` batch: the measurement CSV (and contours) at ``path``, the truth
    beside it (``<stem>_truth.csv``); returns both paths."""
    from capsmech.diagnosis.undeclared_tube import write_batch as write_rows

    return write_rows(batch, path)


def compare_methods(database: DatabaseLike = "shear-paper", lambda_database: DatabaseLike = "shear-microrheometry",
                    lambda_value: str = "0.001", laws: str | Iterable[str] | None = None) -> list[MethodComparison]:
    """The paper's microrheometry against its microfluidics, before and after the viscosity
    ratio of its shear experiment (``capsmech.inversion.microrheometry``).

    Parameters
    ----------
    database : Database, str or Path
        The shear database made with viscosity ratio 1 (default ``"shear-paper"``).
    lambda_database : Database, str or Path
        The one at the experiment's viscosity ratio (law keys ``<law>+lambda<X>``).
    lambda_value : str
        That ratio as the law keys spell it (default ``"0.001"``).
    laws : str or iterable of str, optional
        Base law keys (default NH, GH_nu0.5 and GH_nu0.2, the paper's).

    Returns
    -------
    list of MethodComparison
        One per law: the paper's example capsule's G_s before and after, the correction's mean
        and extremes over the population's D12, the microrheometry G_s [N/m] before and after,
        the microfluidics G_s.

    Raises
    ------
    DatabaseError
        A database of another flow, or a law key one of them does not hold.
    """
    from capsmech.inversion.microrheometry import compare_methods as compare

    base = as_database(database, "shear", "compare_methods (database)")
    with_lambda = as_database(lambda_database, "shear", "compare_methods (lambda_database)")
    keys = check_laws(base, ["NH", "GH_nu0.5", "GH_nu0.2"] if laws is None else laws, "laws")
    suffix = f"+lambda{lambda_value}"
    missing = [law + suffix for law in keys if law + suffix not in with_lambda.laws]
    if missing:
        raise DatabaseError(f"lambda_database: {_label(with_lambda)} has no law group {', '.join(missing)} "
                            f"(it has {', '.join(with_lambda.laws)}); refill it with `make database GRID=microrheometry`")
    return compare(base, with_lambda, suffix, tuple(keys))


#: The grid whose model choices a single kernel run takes when its arguments leave them open: the
#: paper's, so that a case run by hand is comparable with (and as steady as) the shipped databases'.
REFERENCE_GRID = "paper"


def _kernel_flag(args: Sequence[str], flag: str) -> str | None:
    """The value of ``flag`` (``--flag V`` or ``--flag=V``) in kernel arguments, the last one given."""
    found = None
    for i, arg in enumerate(args):
        if arg == flag and i + 1 < len(args):
            found = args[i + 1]
        elif arg.startswith(flag + "="):
            found = arg.split("=", 1)[1]
    return found


def database_settings(kernel_args: Sequence[str]) -> list[str]:
    """The reference grid's model choices (integrator, bending regularisation) that
    ``kernel_args`` leave open, as kernel flags. Empty for a namelist run, a branch, help, an
    unreadable Ca_s, or where the grid file is not at hand."""
    flow, ca = _kernel_flag(kernel_args, "--flow"), _kernel_flag(kernel_args, "--ca")
    if flow not in ("tube", "shear") or ca is None or "--help" in kernel_args or "-h" in kernel_args \
            or _kernel_flag(kernel_args, "--namelist") is not None or _kernel_flag(kernel_args, "--branch-ca"):
        return []
    from capsmech.workflow.grid import GridError, load_grid, model_choice_flags
    from capsmech.workflow.paths import repo_root

    try:
        Ca_s = float(ca)
        grid = load_grid(repo_root() / "config" / f"{REFERENCE_GRID}.yaml")
    except (ValueError, FileNotFoundError, GridError):
        return []
    flags = model_choice_flags(grid, flow, Ca_s)
    return [item for flag, value in zip(flags[::2], flags[1::2])
            if _kernel_flag(kernel_args, flag) is None for item in (flag, value)]


@dataclass
class SimulationRun:
    """One run of the capsim kernel.

    Attributes
    ----------
    returncode : int
        The kernel's exit status (0: the run ended normally; the case's ``status`` says whether
        it reached a steady state).
    arguments : list of str
        The arguments it ran with (those given, then ``added``).
    added : list of str
        The reference grid's settings added because the arguments left them open.
    case_path : Path or None
        The case file this run wrote (``--out``), None when it wrote none.
    """

    returncode: int
    arguments: list[str]
    added: list[str]
    case_path: Path | None


def simulate(kernel_args: Sequence[str], *, database_defaults: bool = True,
             output: Any = None) -> SimulationRun:
    """Run the capsim kernel on one case, its output streamed line by line.

    Parameters
    ----------
    kernel_args : sequence of str
        The kernel's arguments (``["--flow", "shear", "--ca", "0.05", "--out", "case.h5"]``;
        ``capsim --help`` lists them). The folder of ``--out`` is created.
    database_defaults : bool
        Add the reference grid's model choices the arguments leave open (``database_settings``),
        so that the case is computed as the shipped databases' are.
    output : text stream, optional
        Where the kernel's output goes (default ``sys.stdout``).

    Returns
    -------
    SimulationRun
        The exit status, the arguments, and the case file written (``read_case`` reads it).

    Raises
    ------
    FileNotFoundError
        No kernel (``make build``, or the ``CAPSIM`` variable).
    """
    import subprocess
    import sys
    import time

    from capsmech.workflow.paths import capsim_executable
    from capsmech.workflow.simulate import relay_kernel_output

    exe = capsim_executable()
    added = database_settings(kernel_args) if database_defaults else []
    arguments = [*kernel_args, *added]
    stream = sys.stdout if output is None else output
    out_text = _kernel_flag(arguments, "--out")
    out = Path(out_text) if out_text else None
    if out is not None:
        out.parent.mkdir(parents=True, exist_ok=True)
    started = time.time()
    stream.flush()
    with subprocess.Popen([str(exe), *arguments], stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                          bufsize=1) as proc:
        assert proc.stdout is not None
        try:
            # On a terminal the kernel's progress lines become one bar; elsewhere they pass through.
            relay_kernel_output(proc.stdout, stream)
            code = proc.wait()
        except KeyboardInterrupt:
            proc.terminate()
            proc.wait()
            raise
    # A case file older than the run is not this run's (the kernel stopped before writing).
    wrote = out is not None and out.is_file() and out.stat().st_mtime >= started - 1.0
    return SimulationRun(code, arguments, added, out if wrote else None)


def read_case(path: str | Path) -> CaseResult:
    """A case file written by the kernel (``capsmech.io.case.CaseResult``: parameters, status,
    steady values with their units, history, mesh)."""
    from capsmech.io.case import read_case as read

    return read(path)
