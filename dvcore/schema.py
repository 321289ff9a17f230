"""Every table and JSON document dropvision and identify write: one declaration each.

Each declaration names its columns (or keys) with dtype, unit and meaning, and carries one schema
id with a version (``"dropvision.frames/1"``). Writers take column order and ids from here;
readers check what they load with :func:`check_table` / :func:`check_document`, which raise
:class:`SchemaError` naming the file and the mismatch. ``docs/FORMAT.md`` documents the outputs
from :func:`markdown` (a test keeps the two identical).

Also the accepted physical ranges of the inputs (:data:`RANGES`: sequence.json, model files) and
the quality codes of the frames table (:class:`Quality`, :data:`QUALITY_CODES`).

This module sits in the foundation layer (:mod:`dvcore`: it knows nothing of images or models),
so that the measurement, modelling and application layers all stand on it.
"""

from __future__ import annotations

from dataclasses import dataclass

__all__ = [
    "Field", "Table", "Document", "SchemaError", "TABLES", "DOCUMENTS", "TUNING", "TUNING_RUN", "PREDICTION", "TABULAR_MODEL",
    "TABULAR_PREDICTION", "TABULAR_TUNING", "TABULAR_TUNING_RUN", "TABULAR_DESIGN", "Quality",
    "QUALITY_CODES", "RANGES", "check_table", "check_document", "markdown",
]


class SchemaError(ValueError):
    """A table or document that does not match its declaration (the message names the file)."""


@dataclass(frozen=True)
class Field:
    """One column of a table or one key of a document.

    Attributes
    ----------
    name : str
    dtype : str
        ``float``, ``int`` (nullable ``Int64`` in tables where ``nullable``), ``bool``, ``str``,
        ``id`` (int or str), ``object`` (a nested JSON value), ``list``.
    unit : str
        Physical unit ("" for none).
    meaning : str
    nullable : bool
        NaN/None allowed.
    required : bool
        Must be present (documents); every table column is required.
    """

    name: str
    dtype: str
    unit: str
    meaning: str
    nullable: bool = True
    required: bool = True


@dataclass(frozen=True)
class Table:
    """A Parquet table: file name, schema id and columns (in order)."""

    name: str
    file: str
    schema: str
    columns: tuple[Field, ...]
    description: str

    @property
    def column_names(self) -> list[str]:
        return [c.name for c in self.columns]


@dataclass(frozen=True)
class Document:
    """A JSON document: file name, schema id (``schema`` key) and its keys."""

    name: str
    file: str
    schema: str
    keys: tuple[Field, ...]
    description: str
    aliases: tuple[str, ...] = ()

    @property
    def key_names(self) -> list[str]:
        return [k.name for k in self.keys]


F = Field

# ----------------------------------------------------------------------------- per-frame table
FRAMES = Table("frames", "frames.parquet", "dropvision.frames/1", (
    F("file", "str", "", "image file (relative to the sequence folder)", nullable=False),
    F("page", "int", "", "page of a multi-page TIFF (null for single images)"),
    F("delay_us", "float", "us", "strobe delay after the firing trigger", nullable=False),
    F("repeat", "int", "", "index among frames at the same delay (0, 1, ...)", nullable=False),
    F("attached", "bool", "", "the liquid is still joined to the nozzle", nullable=False),
    F("attached_volume_nl", "float", "nl", "volume of the liquid joined to the nozzle, below the tip plane"),
    F("grown_volume_nl", "float", "nl", "attached volume minus the initial meniscus (until pinch-off)"),
    F("drop_volume_nl", "float", "nl", "volume of the main detached drop's silhouette (a satellite touching it "
      "included)"),
    F("detached_volume_nl", "float", "nl", "volume of every detached body (main drop + satellites)"),
    F("drop_z_um", "float", "um", "main-drop centroid along the jetting axis from the tip plane"),
    F("drop_x_um", "float", "um", "main-drop centroid across the axis"),
    F("n_satellites", "int", "", "satellite drops in the frame (one touching the main drop included)"),
    F("flow_velocity_m_s", "float", "m/s", "average flow velocity through the nozzle (growth rate / nozzle area)"),
    F("quality", "str", "", "'ok' or the quality codes joined by '; ' (table below)", nullable=False),
    F("drop_length_um", "float", "um", "extent of the main drop along the axis"),
    F("drop_diameter_um", "float", "um", "extent of the main drop across the axis"),
    F("inflight", "bool", "", "the main drop is compact and in flight (used for in-flight volume and velocity)",
      nullable=False),
    F("neck_px", "float", "px", "narrowest width of the neck while attached"),
    F("gain", "float", "", "illumination of the frame relative to the background model"),
    F("blur_px", "float", "px", "edge blur (Gaussian sigma) measured at the nozzle walls (NaN, flagged blurred, "
      "where the walls show no edge)"),
    F("wall_contrast", "float", "", "contrast of the nozzle walls against the background"),
    F("attached_volume_uncertainty_nl", "float", "nl", "standard uncertainty of attached_volume_nl (edge position, "
      "the body's edge definition, blur correction; dropvision.frame.volume.volume_uncertainty_px3, "
      "dropvision.frame.volume.edge_definition_px)"),
    F("grown_volume_uncertainty_nl", "float", "nl", "standard uncertainty of grown_volume_nl"),
    F("drop_volume_uncertainty_nl", "float", "nl", "standard uncertainty of drop_volume_nl"),
    F("detached_volume_uncertainty_nl", "float", "nl", "standard uncertainty of detached_volume_nl"),
    F("volume_uncertainty_source", "str", "", "what dominates the edge-position error common to the sequence's "
      "volumes: background level, clipped background", nullable=False),
), "One row per frame, in delay order (repeats kept).")

#: Classes of the bodies table (`dropvision.output.bodies_table`), in the order the rules are tried.
BODY_CLASSES = ("nozzle", "attached", "mist", "dust", "border", "noise", "main_drop", "satellite", "tail")

BODIES = Table("bodies", "bodies.parquet", "dropvision.bodies/1", (
    F("file", "str", "", "image file (relative to the sequence folder)", nullable=False),
    F("page", "int", "", "page of a multi-page TIFF (null for single images)"),
    F("delay_us", "float", "us", "strobe delay after the firing trigger", nullable=False),
    F("repeat", "int", "", "index among frames at the same delay", nullable=False),
    F("body_id", "int", "", "body number within the frame (0, 1, ... in the order listed)", nullable=False),
    F("body_class", "str", "", "one of " + ", ".join(BODY_CLASSES) + " (rules in docs/BODIES.md)",
      nullable=False),
    F("reason", "str", "", "why the body got its class, with the figures compared", nullable=False),
    F("counted", "bool", "", "counted in n_satellites of the frames table", nullable=False),
    F("area_px", "int", "px", "pixels of the body's silhouette (lens spot filled)", nullable=False),
    F("volume_nl", "float", "nl", "disc-integrated volume (attached: below the tip plane; null for nozzle)"),
    F("row_px", "float", "px", "centroid row in the canonical frame (nozzle at the top)"),
    F("col_px", "float", "px", "centroid column in the canonical frame"),
    F("row_camera_px", "float", "px", "centroid row in the frame as the camera stored it (orientation undone)"),
    F("col_camera_px", "float", "px", "centroid column in the frame as the camera stored it"),
    F("z_um", "float", "um", "centroid along the jetting axis from the tip plane"),
    F("x_um", "float", "um", "centroid across the axis"),
    F("min_transmission", "float", "", "darkest transmission inside the body (background = 1)"),
    F("edge_blur_px", "float", "px", "edge spread of the body (same estimator as edge_blur_ref_px)"),
    F("edge_blur_ref_px", "float", "px", "edge spread of the in-focus nozzle walls in the calibration frame"),
), "One row per dark body per frame: what it is and why (satellites are counted from it).")

#: Frames-table columns summarised per delay in per_delay.parquet, with their units.
PER_DELAY_SOURCES = (("attached_volume_nl", "nl"), ("grown_volume_nl", "nl"), ("drop_volume_nl", "nl"),
                     ("detached_volume_nl", "nl"), ("drop_z_um", "um"), ("drop_x_um", "um"),
                     ("n_satellites", ""), ("flow_velocity_m_s", "m/s"))

PER_DELAY = Table("per_delay", "per_delay.parquet", "dropvision.per-delay/1", (
    F("delay_us", "float", "us", "strobe delay", nullable=False),
    F("n_frames", "int", "", "frames at this delay", nullable=False),
    *(F(f"{c}_{stat}", "float", unit if stat != "count" else "", f"{stat} of {c} over the frames at this delay")
      for c, unit in PER_DELAY_SOURCES for stat in ("mean", "std", "count")),
    F("attached_fraction", "float", "", "fraction of the frames at this delay still attached"),
), "Statistics of the frames table over repeated frames at one delay.")

#: Columns of shots.parquet taken as they are from the frames table (one place per concept).
SHOTS_FROM_FRAMES = ("delay_us", "drop_volume_nl", "drop_volume_uncertainty_nl", "drop_length_um", "drop_diameter_um",
                     "n_satellites", "drop_z_um", "drop_x_um", "attached_volume_nl", "attached_volume_uncertainty_nl",
                     "inflight", "quality")

SHOTS = Table("shots", "shots.parquet", "dropvision.shots/1", (
    F("file", "str", "", "image file (relative to the shot folder; the path as given for files of several folders)",
      nullable=False),
    F("delay_us", "float", "us", "strobe delay of the shot (--delay-us, else 0 assumed: summary.json "
      "shots[].delay_source)", nullable=False),
    F("drop_volume_nl", "float", "nl", "volume of the main detached drop (frames.parquet drop_volume_nl)"),
    F("drop_volume_uncertainty_nl", "float", "nl", "its standard uncertainty"),
    F("drop_sphere_diameter_um", "float", "um", "diameter of the sphere of drop_volume_nl, (6 V / pi)^(1/3)"),
    F("drop_sphere_diameter_uncertainty_um", "float", "um", "its standard uncertainty (one third of the volume's "
      "relative uncertainty)"),
    F("drop_length_um", "float", "um", "extent of the main drop along the jetting axis"),
    F("drop_diameter_um", "float", "um", "extent of the main drop across the jetting axis"),
    F("tail_length_um", "float", "um", "the main drop's tail (ligament): its length beyond a round head as wide as "
      "it, drop_length_um - drop_diameter_um, 0 for a drop no longer than wide; where the drop is not compact (not "
      "in flight) the quality holds tail_joined and a note gives the tail"),
    F("drop_velocity_m_s", "float", "m/s", "main-drop velocity along the jetting axis from a double exposure: the "
      "distance between its two images over the strobe interval (the shot's strobe_interval_us label, else "
      "measure_shots strobe_interval_us); NaN with a note where none is given or the second image is not found"),
    F("drop_velocity_uncertainty_m_s", "float", "m/s", "its standard uncertainty (half a pixel on each centroid, "
      "the pixel size's)"),
    F("n_satellites", "int", "", "satellite drops (one touching the main drop included)"),
    F("satellites_volume_nl", "float", "nl", "volume of the detached bodies other than the main drop's silhouette "
      "(detached_volume_nl - drop_volume_nl of frames.parquet; a satellite touching the main drop is in the drop's)"),
    F("drop_z_um", "float", "um", "main-drop centroid along the jetting axis from the tip plane"),
    F("drop_x_um", "float", "um", "main-drop centroid across the jetting axis"),
    F("trajectory_angle_mrad", "float", "mrad", "IEC 62899-302-3 trajectory angle: the projected angle, in the image "
      "plane, between the jetting axis and the drop's path from the nozzle exit (axis at the tip plane) to the "
      "main-drop centroid, atan(drop_x_um / drop_z_um); NaN with a note where the nozzle or the drop is not found"),
    F("attached_volume_nl", "float", "nl", "liquid joined to the nozzle below the tip plane (pendant drop)"),
    F("attached_volume_uncertainty_nl", "float", "nl", "its standard uncertainty"),
    F("pixel_size_um", "float", "um", "the shot's pixel size (given, or its needle's outer diameter over the "
      "needle's width measured in this image: summary.json shots[].pixel_size_source)"),
    F("pixel_size_uncertainty_um", "float", "um", "its standard uncertainty (0 for a given pixel size; from the "
      "needle's width otherwise, in the volumes' uncertainties)"),
    F("inflight", "bool", "", "the main drop is compact and in flight", nullable=False),
    F("quality", "str", "", "'ok' or the quality codes joined by '; ' (table below)", nullable=False),
    F("notes", "str", "", "what is particular to this shot, sentences joined by '; ' (notes common to every shot are "
      "in summary.json)", nullable=False),
), "One row per image of a shot folder (images with no delay to tell, each measured as a single frame), in "
   "file order. The labels follow the declared columns: one float column per label, named by the label as "
   "written in the file name (`V1--86` gives a column `V1` = -86), the `shots.csv` header, the key of "
   "sequence.json's `shots` list or the group of --label-pattern; a label named like a declared column is named `label_<name>`; NaN where a file lacks it.")

SUMMARY = Document("summary", "summary.json", "dropvision.measure/1", (
    F("schema_version", "str", "", "document id"),
    F("sequence", "str", "", "measured sequence folder"),
    F("n_frames", "int", "", "frames in the sequence", nullable=False),
    F("n_measured", "int", "", "frames measured (the others are in errors)", nullable=False),
    F("pinchoff_us", "float", "us", "first delay at which the drop is separated from the meniscus"),
    F("grown_volume_at_pinchoff_nl", "float", "nl", "grown volume in the last attached frame before pinch-off"),
    F("initial_meniscus_volume_nl", "float", "nl", "attached volume at rest (subtracted to give the grown volume)"),
    F("initial_meniscus_source", "str", "", "which frames gave the initial meniscus"),
    F("inflight_volume_nl", "float", "nl", "mean main-drop volume over the in-flight frames"),
    F("inflight_volume_std_nl", "float", "nl", "its standard deviation"),
    F("inflight_volume_uncertainty_nl", "float", "nl", "standard uncertainty of inflight_volume_nl: the frames' "
      "common (edge) uncertainty and the scatter's standard error in quadrature", required=False),
    F("grown_volume_at_pinchoff_uncertainty_nl", "float", "nl", "standard uncertainty of "
      "grown_volume_at_pinchoff_nl", required=False),
    F("initial_meniscus_volume_uncertainty_nl", "float", "nl", "standard uncertainty of "
      "initial_meniscus_volume_nl", required=False),
    F("inflight_frames", "int", "", "in-flight frames used"),
    F("jetting_velocity_m_s", "float", "m/s", "slope of the main-drop position over the in-flight frames"),
    F("jetting_velocity_se_m_s", "float", "m/s", "its standard error"),
    F("trajectory_angle_mrad", "float", "mrad", "angle of the trajectory to the nozzle axis"),
    F("satellites", "int", "", "median satellite count over the in-flight frames"),
    F("max_stroke_us", "float", "us", "instant of maximum stroke (dead time + u2/u1)"),
    F("flow_velocity_at_max_stroke_m_s", "float", "m/s", "flow velocity at that instant"),
    F("calibration", "object", "", "tip row, axis column, tilt, pixel size and their checks"),
    F("errors", "list", "", "frames that could not be read or measured: file, page, delay_us, reason"),
    F("quality_counts", "object", "", "frames per quality text"),
    F("software", "object", "", "versions of Python and of every package the result depends on"),
    F("config", "object", "", "the measurement configuration (MeasureConfig)"),
    F("notes", "list", "", "plausibility notes, short sentences: what in the input looks like a lie and what "
      "was done about it (empty when nothing)", required=False),
    F("orientation", "str", "", "direction the drops travel in the stored images (down, up, left, right)",
      required=False),
    F("orientation_source", "str", "", "where the orientation came from: sequence.json, an option (\"command line "
      "--orientation\"), \"detected in FILE: ...\" (the edge the nozzle or holder touches) or \"default (down): "
      "not detected ...\" with what was seen at each edge", required=False),
    F("pixel_size_source", "str", "", "where the pixel size came from: sequence.json, an option, TIFF metadata (ome, "
      "imagej, tiff-description), or \"nozzle outer diameter D um / W px (median over N frames ...)\"",
      required=False),
    F("nozzle_outer_diameter_source", "str", "", "where nozzle_outer_diameter_um came from (null: not given)",
      required=False),
    F("nozzle_inner_diameter_source", "str", "", "where nozzle_inner_diameter_um came from (null: not given)",
      required=False),
    F("delay_source", "str", "", "where the frames' delays came from (file names, frames list, frame_rate_hz, an "
      "option, or assumed 0 us for one frame without a delay)", required=False),
    F("waveform_source", "str", "", "where the waveform came from (null: not given)", required=False),
    F("bit_depth_source", "str", "", "where the bit depth came from", required=False),
), "One per measured sequence; with the versions and the configuration the result is reproducible.")

SHOTS_SUMMARY = Document("shots_summary", "summary.json", "dropvision.analysis.shots-summary/1", (
    F("schema_version", "str", "", "document id"),
    F("kind", "str", "", "\"shots\": a folder of independent shots (a sequence's summary.json has no kind)"),
    F("inputs", "list", "", "the folder (or the image files) measured"),
    F("n_shots", "int", "", "images found", nullable=False),
    F("n_measured", "int", "", "images measured (the others are in errors)", nullable=False),
    F("labels", "list", "", "label names, in the order of the shots.parquet columns"),
    F("label_sources", "object", "", "label name -> where it was read: file names, --label-pattern, sequence.json "
      "(its shots list), shots.csv (several joined by ' and ')"),
    F("label_columns", "object", "", "label name -> its column in shots.parquet"),
    F("drop_volume_median_nl", "float", "nl", "median main-drop volume over the measured shots"),
    F("drop_volume_min_nl", "float", "nl", "smallest main-drop volume"),
    F("drop_volume_max_nl", "float", "nl", "largest main-drop volume"),
    F("drop_sphere_diameter_median_um", "float", "um", "median sphere-equivalent diameter of the main drop"),
    F("n_satellites_median", "float", "", "median satellite count"),
    F("trajectory_angle_median_mrad", "float", "mrad", "median trajectory angle"),
    F("attached_volume_median_nl", "float", "nl", "median attached (pendant) volume"),
    F("quality_counts", "object", "", "shots per quality text"),
    F("errors", "list", "", "images that could not be measured: file, reason"),
    F("notes", "list", "", "notes common to every shot (the others are in the shots' notes column)"),
    F("shots", "list", "", "per image: file, its labels, then orientation, the *_source keys of a sequence's "
      "summary.json, shared_calibration (true: measured with the calibration the shots share), notes and "
      "calibration, or error (why it could not be measured)"),
    F("shared_calibration", "object", "", "the calibration the shots of one rig share (dropvision.analysis.shot_rig): "
      "reference (the shot the others are checked against), calibrated_from (the shots it comes from), left_out "
      "(calibration shots that agree with no group: file, reason), others (the same for each further group of "
      "agreeing calibration shots, up to dropvision.analysis.shot_rig.MAX_GROUPS: another rig, or the holder at another "
      "place; a shot takes the first that holds for it); reference null and a reason where every shot was calibrated alone"),
    F("waveform", "object", "", "the waveform template whose parameters are each shot's labels (sequence.json "
      "`waveform` or --waveform-template without parameters): {template, <constant>, dead_time_us, "
      "parameters_from: \"labels\"}; the parameters are the label columns of shots.parquet of the same names, in "
      "the template's units (absent where no template waits for the labels)", required=False),
    F("software", "object", "", "versions of Python and of every package the result depends on"),
    F("config", "object", "", "the measurement configuration (MeasureConfig)"),
), "summary.json of a shot folder (`dropvision measure` over images with no delay to tell).")

# ----------------------------------------------------------------------------- campaign dataset
#: u1/u2 columns of the campaign dataset: the paper's trapezoid only (issue 31)
_TRAPEZOID_ONLY = ("(the paper's trapezoid; absent in a dataset of another waveform template, whose parameters take "
                   "its place)")
_TEMPLATE_COLUMNS = ("A dataset of another waveform template than the paper's trapezoid (dataset.json `waveform`: "
                     "three_pulse, segments) has, in place of u1_um_per_ms and u2_um, one float column per parameter "
                     "of the template, named and in the unit as it declares them (dataset.json "
                     "`waveform_parameters`: `V1` in V, `w1` in us, ...).")
TIMESERIES = Table("timeseries", "timeseries.parquet", "dropvision.timeseries/1", (
    F("sequence_id", "id", "", "sequence (its folder relative to the campaign root)", nullable=False),
    F("u1_um_per_ms", "float", "um/ms", "stroke velocity u1 " + _TRAPEZOID_ONLY, nullable=False, required=False),
    F("u2_um", "float", "um", "stroke u2 " + _TRAPEZOID_ONLY, nullable=False, required=False),
    F("delay_us", "float", "us", "strobe delay after the trigger", nullable=False),
    F("grown_volume_nl", "float", "nl", "grown volume (initial meniscus subtracted); NaN only once detached"),
    F("flow_velocity_m_s", "float", "m/s", "average flow velocity in the nozzle"),
    F("attached", "bool", "", "every frame at this delay shows the drop joined to the nozzle", nullable=False),
), "Training time series: one row per sequence and strobe delay. " + _TEMPLATE_COLUMNS)

DATASET_SUMMARY = Table("dataset_summary", "summary.parquet", "dropvision.dataset-summary/1", (
    F("sequence_id", "id", "", "sequence", nullable=False),
    F("u1_um_per_ms", "float", "um/ms", "stroke velocity u1 " + _TRAPEZOID_ONLY, nullable=False, required=False),
    F("u2_um", "float", "um", "stroke u2 " + _TRAPEZOID_ONLY, nullable=False, required=False),
    F("pinchoff_us", "float", "us", "pinch-off instant after the trigger"),
    F("grown_volume_at_pinchoff_nl", "float", "nl", "grown volume right before pinch-off"),
    F("inflight_volume_nl", "float", "nl", "in-flight drop volume"),
    F("jetting_velocity_m_s", "float", "m/s", "jetting velocity"),
    F("flow_velocity_at_max_stroke_m_s", "float", "m/s", "flow velocity at maximum stroke (NaN in a dataset of "
      "another waveform template)"),
    F("inflight_volume_std_nl", "float", "nl", "scatter of the in-flight volume", required=False),
    F("jetting_velocity_se_m_s", "float", "m/s", "standard error of the jetting velocity", required=False),
    F("satellites", "float", "", "satellite count", required=False),
    F("n_frames", "float", "", "frames measured", required=False),
    F("n_errors", "float", "", "frames skipped", required=False),
    F("pixel_size_ratio", "float", "", "pixel size implied by the nozzle's outer diameter / the given one "
      "(summary.json calibration); sets the pixel-size part of the intervals' measurement term", required=False),
    F("pixel_size_ratio_uncertainty", "float", "", "its standard uncertainty", required=False),
    F("inflight_frames", "float", "", "in-flight frames behind inflight_volume_nl (its standard error: "
      "inflight_volume_std_nl / sqrt(inflight_frames))", required=False),
), "Training summary: one row per sequence. " + _TEMPLATE_COLUMNS)

DATASET_SHOTS = Table("dataset_shots", "shots.parquet", "dropvision.dataset-shots/1", (
    F("shot_folder", "str", "", "the shot folder (its path relative to the campaign root)", nullable=False),
    *SHOTS.columns,
), "`dropvision campaign`: the rows of every shot folder below the campaign root (a folder of images with no "
   "delay to tell, measured as `dropvision measure` measures it: its shots.parquet), one row per image, the "
   "folders in id order; then the label columns of all folders (NaN where a folder lacks the label; a label "
   "named `shot_folder` is named `label_shot_folder`). Written where the campaign holds shot folders.")

DATASET = Document("dataset", "dataset.json", "dropvision.dataset/1", (
    F("schema", "str", "", "document id"),
    F("nozzle_inner_diameter_um", "float", "um", "nozzle inner diameter", nullable=False),
    F("sample_interval_us", "float", "us", "strobe interval", nullable=False),
    F("dead_time_us", "float", "us", "trigger-to-piston dead time (default 220)", required=False),
    F("u3_um_per_ms", "float", "um/ms", "instroke velocity (default 2)", required=False),
    F("hold_us", "float", "us", "hold time (default 20)", required=False),
    F("waveform", "object", "", "the waveform template every sequence shares and its constants ({template, "
      "<constant>}: identify.waveform); absent: the paper's trapezoid in u1_um_per_ms, u2_um (u3_um_per_ms, "
      "hold_us)", required=False),
    F("waveform_parameters", "object", "", "with `waveform`: parameter name -> unit, in the template's order: the "
      "columns of summary.parquet and timeseries.parquet in place of u1_um_per_ms, u2_um", required=False),
    F("ink", "object", "", "density_kg_m3, viscosity_mPa_s, surface_tension_mN_m", required=False),
    F("nozzle", "object", "", "length_mm, reservoir_channel_radius_um, reservoir_channel_length_mm",
      required=False),
    F("pixel_size_um", "float", "um", "pixel size of the images when every sequence has the same (else null)",
      required=False),
    F("pixel_size_um_by_sequence", "object", "um", "sequence id -> its pixel size, when they differ (each "
      "sequence carries its own scale; the dataset is in physical units)", required=False),
    F("measurement_uncertainty", "object", "", "systematic measurement uncertainty shared by every sequence "
      "(relative standard uncertainties, 1 sigma): volume_rel and velocity_rel (used as given), or "
      "pixel_size_rel (calibration of the pixel size, combined with the method's 0.1 % volume / 0.2 % "
      "velocity); pinchoff_std_us; source (text). Absent: from the pixel-size check of the campaign, else "
      "defaults (identify.measurement_uncertainty.measurement_uncertainty)", required=False),
    F("sequences", "list", "", "sequence ids measured", required=False),
    F("failed", "object", "", "sequence id -> why it failed", required=False),
    F("shot_folders", "list", "", "shot folders measured into shots.parquet (ids relative to the campaign root; "
      "absent where the campaign holds none)", required=False),
    F("n_shots", "int", "", "rows of shots.parquet (absent where the campaign holds no shot folder)",
      required=False),
    F("versions", "object", "", "software versions", required=False),
), "Campaign dataset metadata (also written by identify's Dataset.save).", aliases=("identify.dataset/1",))

MANIFEST = Document("manifest", "manifest.json", "dropvision.manifest/1", (
    F("schema", "str", "", "document id"),
    F("root", "str", "", "campaign root folder"),
    F("versions", "object", "", "software versions"),
    F("sequences", "object", "", "sequence (or shot folder) id -> path, input_hash, shard, status, error, meta; "
      "kind \"shots\" for a shot folder (its shard holds shots.parquet)"),
), "Campaign progress: what was measured from which inputs (resumable).")

MODEL = Document("model", "model.json", "identify.hybrid-model/1", (
    F("schema", "str", "", "document id"),
    F("ecm", "object", "", "ECM coefficients A3..B0 (SI), their covariance and physical parameters; level "
      "(optional): physical (La..Kc given Eq. 2) or coefficients (A3..B0 fitted directly, scale A3 = 1, "
      "parameters null: not identifiable without ink and reservoir geometry); absent in older models: physical"),
    F("pinchoff", "object", "", "pinch-off polynomial in (u1, u2), us"),
    F("volume_adjuster", "object", "", "volume adjuster polynomial, nl"),
    F("velocity_adjuster", "object", "", "velocity adjuster polynomial, m/s"),
    F("nozzle_inner_diameter_um", "float", "um", "nozzle inner diameter"),
    F("versions", "object", "", "software versions", required=False),
    F("intervals", "object", "", "what the mean-drop (confidence) and one-drop (prediction) intervals need beyond "
      "the parameters: per output (pinchoff_us, inflight_volume_nl, jetting_velocity_m_s) drop_std, dof, source "
      "(repeats|sequence_se|smooth_scatter|residuals), model_std (global model discrepancy), local (optional: "
      "Gaussian process of the cross-validation errors for the local model discrepancy: u1_um_per_ms, u2_um, "
      "cv_error, centre, scale, lengthscale, discrepancy_variance, scatter_variance, likelihood_ratio), cv_rmse, "
      "in_sample_rmse; pinchoff_volume_cross_covariance (scaled bases); measurement "
      "(systematic measurement uncertainty in both intervals: volume_rel, velocity_rel, pixel_size_rel, pinchoff_std_us, source; absent "
      "in older models: no term); flexible (optional: per output the more flexible polynomial the chosen order's "
      "bias is measured against, model_std_source 'polynomial_bias' where that bias exceeds the model discrepancy, "
      "identify.discrepancy.polynomial_bias); flexible_u1 (optional: the same for the reference flexible in u1, order (4, 1) "
      "or the chosen order where larger, counted at a control only where its departure is significant); absent in older models",
      required=False),
    F("notes", "list", "", "what the fit dropped or changed and why (irregular campaigns, ECM level); absent in "
      "older models", required=False),
), "Identified hybrid model (Eq. 8).")

OUTPUT_MARKER = Document("output_marker", ".dropvision-output.json", "dropvision.output-marker/1", (
    F("schema", "str", "", "document id"),
    F("kind", "str", "", "what the folder holds"),
    F("written_by", "str", "", "dropvision version"),
    F("files", "list", "", "files we wrote there (a folder is replaced only if it holds nothing else)"),
), "Ownership marker of every folder we write.")

# ----------------------------------------------------------------------------- live measurement
LIVE_FRAMES = Table("live_frames", "live/frames.jsonl", "dropvision.live-frames/1", (
    F("file", "str", "", "image file (relative to the sequence folder)", nullable=False),
    F("page", "int", "", "page of a multi-page TIFF (null for single images)"),
    F("delay_us", "float", "us", "strobe delay after the firing trigger", nullable=False),
    F("repeat", "int", "", "index among the frames complete so far at the same delay", nullable=False),
    F("attached_volume_nl", "float", "nl", "volume of the liquid joined to the nozzle, below the tip plane"),
    F("attached_volume_uncertainty_nl", "float", "nl", "standard uncertainty of attached_volume_nl"),
    F("n_detached", "int", "", "in-focus detached bodies (main drop, satellites, tails)", nullable=False),
    F("drop_volume_nl", "float", "nl", "volume of the largest in-focus detached body"),
    F("drop_z_um", "float", "um", "its centroid along the jetting axis from the tip plane"),
    F("drop_x_um", "float", "um", "its centroid across the axis"),
    F("quality", "str", "", "the frame's own quality codes ('ok' when none)", nullable=False),
    F("blur_px", "float", "px", "edge blur (Gaussian sigma) measured at the nozzle walls (NaN, flagged blurred, "
      "where the walls show no edge)"),
    F("gain", "float", "", "illumination of the frame relative to the background model"),
    F("error", "str", "", "why the frame could not be read (null when it was measured)"),
    F("calibration_frames", "int", "", "complete frames the calibration it was measured with was made from",
      nullable=False),
    F("size", "int", "bytes", "file size when it was measured (a restart skips it while unchanged)", nullable=False),
    F("mtime_ns", "int", "ns", "file modification time when it was measured (Unix epoch)", nullable=False),
    F("row_unix_s", "float", "s", "when the row was written (Unix epoch)", nullable=False),
    F("latency_ms", "float", "ms", "from the file's last modification to its row", nullable=False),
), "`dropvision watch`: one JSON line per frame as it is measured, before the sequence-level analysis (a shot: "
   "its row as the image alone gives it, calibration_frames 1; its shots.parquet row is written first) "
   "(provisional: pinch-off, grown volume, tracking and the final quality codes are in frames.parquet at the "
   "end). Appended one whole line at a time; read with `dropvision.app.live_journal.read_journal`.")

WATCH = Document("watch", "live/watch.json", "dropvision.watch/1", (
    F("schema", "str", "", "document id"),
    F("sequence", "str", "", "the watched sequence folder"),
    F("kind", "str", "", "shots: the folder received one image per shot (shots.parquet grows as they are measured); "
      "absent: a sequence", required=False),
    F("state", "str", "", "watching (a restart on the same output resumes) or finished"),
    F("ended_by", "str", "", "frames (the expected count), idle (--idle-s), interrupt (Ctrl-C, SIGTERM) or next "
      "sequence (--sequences: the next sub-folder appeared)",
      required=False),
    F("n_live", "int", "", "frames measured live by the last run", required=False),
    F("n_resumed", "int", "", "frames found in the journal of an earlier run", required=False),
    F("latency_ms_median", "float", "ms", "median time from a file's completion to its row, over the frames "
      "written while watching", required=False),
    F("latency_ms_max", "float", "ms", "the longest of those times", required=False),
    F("left_out", "list", "", "files still being written when the watch ended (not in the tables)",
      required=False),
), "`dropvision watch`: what the watch of a sequence folder (or of a folder of shots) did.")

# ----------------------------------------------------------------------------- closed-loop tuning
TUNING_COLUMNS_PER_OUTPUT = (("volume", "nl", "in-flight volume"), ("velocity", "m_s", "jetting velocity"))


def _tuning_columns() -> tuple:
    cols = [F("shot", "int", "", "shot number, 1 = the open-loop `identify design` proposal", nullable=False),
            F("u1_um_per_ms", "float", "um/ms", "proposed stroke velocity", nullable=False),
            F("u2_um", "float", "um", "proposed stroke", nullable=False),
            F("feasible", "bool", "", "the corrected target lies inside the printable region", nullable=False)]
    for o, unit, what in TUNING_COLUMNS_PER_OUTPUT:
        u = unit.replace("_", "/")
        cols += [
            F(f"design_target_{o}_{unit}", "float", u, f"{what} asked of the model: the target / (1 + bias before the "
              "shot); NaN without a target"),
            F(f"predicted_{o}_{unit}", "float", u, f"the model's nominal {what} at (u1, u2)"),
            F(f"corrected_{o}_{unit}", "float", u, f"predicted x (1 + bias before the shot)"),
            F(f"{o}_one_drop_low_{unit}", "float", u, f"one-drop (prediction) interval of the corrected {what}: "
              "the model's one-drop interval and the bias's standard error"),
            F(f"{o}_one_drop_high_{unit}", "float", u, "upper end of that interval"),
            F(f"measured_{o}_{unit}", "float", u, f"{what} the rig measured (NaN: not measured)"),
            F(f"measured_{o}_uncertainty_{unit}", "float", u, "its standard uncertainty as the rig gives it (NaN: none)"),
            F(f"{o}_error_percent", "float", "%", f"measured / target - 1 (NaN without a target)"),
            F(f"{o}_bias_percent", "float", "%", f"relative bias of the rig against the model after this shot "
              "(posterior mean)"),
            F(f"{o}_bias_se_percent", "float", "%", "its posterior standard error"),
        ]
    cols.append(F("within_tolerance", "bool", "", "the measured drop meets the targets within the tolerances",
                  nullable=False))
    return tuple(cols)


TUNING = Table("tuning", "tuning.parquet", "identify.tuning/1", _tuning_columns(),
               "Closed-loop tuning (`identify tune`): one row per shot, in order; a rig may add scalar "
               "`rig_*` columns (the simulated printhead: its truth).")

TUNING_RUN = Document("tuning_run", "tuning.json", "identify.tuning-run/1", (
    F("schema", "str", "", "document id"),
    F("target_volume_nl", "float", "nl", "target in-flight volume"),
    F("target_velocity_m_s", "float", "m/s", "target jetting velocity (null: none)"),
    F("volume_tolerance_percent", "float", "%", "a measured volume within this of the target ends the loop"),
    F("velocity_tolerance_percent", "float", "%", "the same for the velocity (with a velocity target)"),
    F("converged", "bool", "", "the last shot met the targets"),
    F("shots_fired", "int", "", "rows of tuning.parquet"),
    F("message", "str", "", "one-line outcome"),
    F("seed", "int", "", "seed of the Monte Carlo draws and the rig"),
    F("shot_budget", "int", "", "most shots allowed"),
    F("prior_bias_percent", "float", "%", "prior standard deviation of the rig's bias beyond the model's interval"),
    F("prior_std_percent", "object", "%", "the prior standard deviation of each output's bias"),
    F("rig", "str", "", "the rig (name or module:function)"),
    F("rig_options", "object", "", "the rig's settings (the simulated printhead: physics factors, frames, delays)"),
    F("model_file", "str", "", "the model file (null: a model in memory)"),
    F("model_sha256", "str", "", "SHA-256 of the model file's bytes"),
    F("versions", "object", "", "software versions"),
), "What a tuning run was run for (`identify tune`); the shots are tuning.parquet.")

# ----------------------------------------------------------------------------- prediction
_OUT = "an output's entry: mean, std and parameters_only_low/high (Monte Carlo)"
_INTERVALS = ("; with the three intervals: mean_drop_* (confidence), one_drop_* (prediction), their stds, "
              "dominant terms and variance shares")
_BLANK = " (its numbers null when the output is impossible, see `impossible`)"
PREDICTION = Document("prediction", "identify predict --json", "identify.prediction/1", (
    F("schema", "str", "", "document id"),
    F("pinchoff_us", "float", "us", "nominal pinch-off instant" + _BLANK),
    F("grown_volume_at_pinchoff_nl", "float", "nl", "nominal grown volume at pinch-off" + _BLANK),
    F("inflight_volume_nl", "object", "nl", _OUT + _INTERVALS + _BLANK),
    F("jetting_velocity_m_s", "object", "m/s", _OUT + _INTERVALS + _BLANK),
    F("pinchoff_us_mc", "object", "us", _OUT + _BLANK),
    F("grown_volume_at_pinchoff_mc_nl", "object", "nl", _OUT + _BLANK),
    F("pinchoff_us_intervals", "object", "us", "the three intervals of the pinch-off instant" + _BLANK),
    F("level", "float", "", "level of the intervals"),
    F("interval_note", "str", "", "what each interval covers"),
    F("measurement", "object", "", "the training campaign's systematic measurement uncertainty (null: none "
      "recorded)"),
    F("extrapolation", "bool", "", "(u1, u2) lies outside the training region (convex hull of the training "
      "controls): the polynomials are unchecked there; null when the model records no training controls"),
    F("training_region", "object", "", "the training region's bounds (u1_um_per_ms, u2_um), shape and number of "
      "controls; null: unknown"),
    F("impossible", "object", "", "output -> why its prediction is physically impossible (a negative volume, "
      "a pinch-off not after the dead time, a jetting velocity <= 0): such an output is null, not a value; "
      "{} when none"),
    F("notes", "list", "", "sentences on the extrapolation and the impossible outputs (empty when none)"),
), "`identify predict --json`: one JSON object on stdout (Python: `HybridModel.predict` warns with "
   "`identify.hybrid.ExtrapolationWarning` and gives NaN for an impossible output).")

# ----------------------------------------------------------------------------- table models (identify.tabular)
TABULAR_MODEL = Document("tabular_model", "model.json", "identify.tabular-model/1", (
    F("schema", "str", "", "document id"),
    F("inputs", "list", "", "the parameter columns, in the user's units (e.g. V3, w1, w2, w3, d1, d2)"),
    F("outputs", "list", "", "the measured columns modelled"),
    F("kinds", "object", "", "output -> continuous | count (non-negative integers, at most 12 distinct values)"),
    F("settings", "object", "", "folds (K of the K-fold cross-validation), seed, level (of the intervals)"),
    F("training_rows", "int", "", "rows of training_data"),
    F("training_sha256", "str", "", "SHA-256 of training_data (canonical JSON): an edit is refused"),
    F("training_source", "str", "", "the table fitted (null: a table in memory)"),
    F("training_data", "object", "", "column -> the training rows' values (null: an output not measured): the "
      "model is refitted from them at load, deterministically given settings.seed (no pickled object)"),
    F("continuous", "object", "", "per continuous output: candidate (the regressor chosen by CV), log (fitted on "
      "the logarithm), q_lo, q_hi (conformal quantiles of the locally scaled out-of-fold residuals: one-drop "
      "interval = fit + [q_lo, q_hi] x scale), rows_fitted, cv (every candidate's mean_abs_error, "
      "median_error_percent, p90_error_percent)"),
    F("counts", "object", "", "per count output: classes seen, steps (P(n = k | n >= k): k, model (the "
      "calibrated classifier chosen by CV Brier, null: the constant rate), rate, cv)"),
    F("training_region", "object", "", "low, high, step (grid step) per input, max_gap_steps (largest distance "
      "between a training row and its nearest other one, in steps)"),
    F("check", "object", "", "rows, predictions (column -> values on the first training rows): the refit at "
      "load must reproduce them (else identify.tabular.RefitMismatchWarning)"),
    F("notes", "list", "", "what the fit left out or noticed"),
    F("versions", "object", "", "software versions (scikit-learn included)"),
), "Models of a table's outputs on its parameters (`identify fit TABLE --inputs ... --outputs ...`, "
   "identify.tabular).")

TABULAR_PREDICTION = Table("tabular_prediction", "predictions.csv", "identify.tabular-prediction/1", (
    F("<input table's columns>", "object", "", "every column of the --table, as read, in order"),
    F("<o>_mean", "float", "of <o>", "per continuous output <o>: the fitted typical value (the median drop; "
      "exp of the log fit for a positive output)"),
    F("<o>_mean_drop_low", "float", "of <o>", "mean-drop (confidence) interval at the model's level: the fit's "
      "uncertainty (delete-a-fold jackknife of the K fold models), no drop-to-drop scatter"),
    F("<o>_mean_drop_high", "float", "of <o>", "its upper end"),
    F("<o>_one_drop_low", "float", "of <o>", "one-drop (prediction) interval at the model's level: locally "
      "scaled split-conformal on the out-of-fold residuals"),
    F("<o>_one_drop_high", "float", "of <o>", "its upper end"),
    F("<o>_p<k>", "float", "", "per count output <o> and count k seen in training: P(<o> = k); the largest k "
      "seen: P(<o> >= k)"),
    F("outside_training_region", "bool", "", "an input outside its min..max seen, or the row farther (in grid "
      "steps) from every training row than any training row from its nearest other one: numbers unchecked",
      nullable=False),
    F("outside_training_region_why", "str", "", "why (empty inside)"),
), "`identify predict model.json --table ROWS --out FILE` with a table model: one row per row of ROWS (CSV, "
   "or Parquet by the suffix).")

WAVEFORM = Document("waveform", "sequence.json `waveform` (template form)", "dropvision.waveform/1", (
    F("template", "str", "", "waveform template (identify.waveform.TEMPLATES): trapezoid (the paper's Eq. 1; "
      "parameters u1_um_per_ms um/ms, u2_um um; constants u3_um_per_ms, hold_us) or three_pulse (a MicroDrop-style "
      "dispenser; parameters V1, V2, V3 in V: pulse amplitudes, w1, w2, w3 in us: pulse widths at half amplitude, "
      "d1, d2 in us: delays from the end of one pulse to the start of the next; constant edge_us) or segments (a "
      "drive the lab declares itself, e.g. a Dimatix multi-segment waveform: constants declare (parameter name -> "
      "unit: us for a duration, the drive's unit for a level), segments (list of [duration, level] from rest, each "
      "a number, a declared name or -name; the last level 0), unit (default V), velocity_segment (the segment at "
      "whose end the jetting velocity is read; null: the first reaching the largest |level|))"),
    F("parameters", "object", "", "parameter name -> value in the template's unit; every declared parameter, no "
      "other"),
    F("<constant>", "object", "of the template", "the template's constants (trapezoid: u3_um_per_ms default 2, "
      "hold_us default 20; three_pulse: edge_us default 2, the rise and fall time of each pulse; segments: declare, "
      "segments, unit, velocity_segment)", required=False),
    F("dead_time_us", "float", "us", "trigger to the start of the drive (default 220)", required=False),
), "The drive as a piecewise-linear function of time in the lab's own parameters (issue 31); the key of "
   "sequence.json (and of `dropvision.synth`'s SynthConfig.waveform). Without `template` the object is the "
   "paper's flat form (u1_um_per_ms, u2_um, ...): the trapezoid template, into which the trapezoid's template "
   "form is also read.")

TEMPLATE_MODEL = Document("template_model", "model.json", "identify.template-model/1", (
    F("schema", "str", "", "document id"),
    F("waveform", "object", "", "the template and its constants ({template, <constant>})"),
    F("parameters", "object", "", "parameter name -> unit, as the template declares them"),
    F("drive_unit", "str", "", "unit of the drive u(t) entering Eq. (6) (um: a piston stroke; V: a piezo voltage, "
      "read as um of equivalent stroke, Kc per V)"),
    F("dead_time_us", "float", "us", "trigger to the start of the drive"),
    F("nozzle_inner_diameter_um", "float", "um", "nozzle inner diameter (flow velocity)"),
    F("inputs", "list", "", "the parameters varied in the training data (the laws' inputs)"),
    F("fixed", "object", "", "parameter -> the value every training sequence had (required at prediction)"),
    F("training_region", "object", "", "varied parameter -> [min, max] seen in training"),
    F("ecm", "object", "", "coefficients A3..B0 (SI), level (physical | coefficients), parameters ({La, Ra, CN, "
      "Kc: value, ci95}, null at level coefficients), rmse_nl, n_sequences, n_samples, units"),
    F("pinchoff", "object", "", "pinch-off instant (us after the trigger) linear in the inputs: inputs, centre, "
      "scale, coefficients (constant first, then per scaled input), rmse, n"),
    F("volume_adjuster", "object", "", "volume adjuster (nl), the same form"),
    F("velocity_adjuster", "object", "", "velocity adjuster (m/s), the same form"),
    F("notes", "list", "", "what the fit left out or kept constant"),
), "Hybrid model on a waveform template (identify.template_fit.TemplateModel).")

TEMPLATE_PREDICTION = Table("template_prediction", "predictions.csv", "identify.template-prediction/1", (
    F("<input table's columns>", "object", "", "every column of the --table, as read, in order (a column per "
      "varied parameter of the model; a fixed parameter's column may be left out)"),
    F("pinchoff_us", "float", "us", "pinch-off instant after the trigger (the model's linear law)", nullable=False),
    F("grown_volume_at_pinchoff_nl", "float", "nl", "ECM grown volume at that instant", nullable=False),
    F("inflight_volume_nl", "float", "nl", "in-flight volume: grown volume + volume adjuster", nullable=False),
    F("jetting_velocity_m_s", "float", "m/s", "jetting velocity: ECM flow velocity at the template's velocity "
      "instant + velocity adjuster", nullable=False),
    F("flow_velocity_at_velocity_instant_m_s", "float", "m/s", "the ECM flow velocity alone at that instant",
      nullable=False),
    F("outside_training_region", "bool", "", "a varied parameter outside its min..max seen in training: numbers "
      "unchecked", nullable=False),
    F("outside_training_region_why", "str", "", "why (\"V1=40 > 34 (max seen)\"; empty inside)", nullable=False),
), "`identify predict model.json --table ROWS --out FILE` with a model on a waveform template: one row per row of "
   "ROWS (CSV, or Parquet by the suffix); no intervals (the template model has none).")

TEMPLATE_SETTING_PREDICTION = Document(
    "template_setting_prediction", "identify predict --set ... --json (template model)",
    "identify.template-setting-prediction/1", (
        F("schema", "str", "", "document id"),
        F("settings", "object", "", "every parameter of the template -> its value (the fixed ones at their "
          "training values)"),
        F("pinchoff_us", "float", "us", "as the predictions.csv column"),
        F("grown_volume_at_pinchoff_nl", "float", "nl", "as the predictions.csv column"),
        F("inflight_volume_nl", "float", "nl", "as the predictions.csv column"),
        F("jetting_velocity_m_s", "float", "m/s", "as the predictions.csv column"),
        F("flow_velocity_at_velocity_instant_m_s", "float", "m/s", "as the predictions.csv column"),
        F("outside_training_region", "bool", "", "a varied parameter outside its range seen in training"),
        F("outside_training_region_why", "str", "", "why (empty inside)"),
    ), "`identify predict model.json --set NAME=VALUE ... --json` with a model on a waveform template: one JSON "
       "object on stdout.")

TABULAR_SETTING_PREDICTION = Document(
    "tabular_setting_prediction", "identify predict --set ... --json (table model)",
    "identify.tabular-setting-prediction/1", (
        F("schema", "str", "", "document id"),
        F("settings", "object", "", "input -> value"),
        F("predicted", "object", "", "the columns of `identify predict --table` (tabular_prediction) other than "
          "the two below: <o>_mean, intervals, <o>_p<k>"),
        F("outside_training_region", "bool", "", "as the predictions.csv column"),
        F("outside_training_region_why", "str", "", "why (empty inside)"),
    ), "`identify predict model.json --set NAME=VALUE ... --json` with a table model: one JSON object on stdout.")

TABULAR_TUNING = Table("tabular_tuning", "tuning.parquet", "identify.tabular-tuning/1", (
    F("shot", "int", "", "shot number, 1 = the open-loop `identify design` proposal", nullable=False),
    F("<input>", "float", "of <input>", "per input of the model, in its order and under its name: the setting "
      "fired (a value of the training lattice, inside the training region)", nullable=False),
    F("<o>_target", "float", "of <o>", "per target output <o>: the target (a count target: the count asked)"),
    F("<o>_predicted", "float", "of <o>", "per continuous target: the model's fit at the setting"),
    F("<o>_corrected", "float", "of <o>", "the fit corrected by the rig's offset learnt before the shot"),
    F("<o>_one_drop_low", "float", "of <o>", "one-drop interval of the corrected value (the model's conformal "
      "quantiles x the drop scatter and the offset's uncertainty)"),
    F("<o>_one_drop_high", "float", "of <o>", "its upper end"),
    F("<o>", "float", "of <o>", "per output the rig measured (every target output): the measured value (NaN: "
      "nothing measured)"),
    F("<o>_error_percent", "float", "%", "per continuous target: measured / target - 1"),
    F("<o>_bias_percent", "float", "%", "the rig's offset from the model at the setting after this shot "
      "(relative; posterior mean)"),
    F("<o>_bias_se_percent", "float", "%", "its posterior standard error"),
    F("<o>_p<k>_predicted", "float", "", "per count target <o> = k: the model's P(<o> = k) at the setting"),
    F("<o>_p<k>_corrected", "float", "", "that probability updated by the counts seen at nearby shots"),
    F("probability_on_target", "float", "", "the corrected probability that one shot meets every target",
      nullable=False),
    F("feasible", "bool", "", "the corrected fit lies within the tolerance and each count target reaches "
      "min_probability", nullable=False),
    F("outside_training_region", "bool", "", "the setting lies outside the training region (never: only "
      "settings inside are proposed)", nullable=False),
    F("within_tolerance", "bool", "", "the measured shot meets every target", nullable=False),
    F("rig_<key>", "float", "", "a number the rig returned that is not an output of the model"),
), "Closed-loop tuning of a table model (`identify tune model.json --target O=V ... --rig module:function`): one "
   "row per shot, in order.")

TABULAR_TUNING_RUN = Document("tabular_tuning_run", "tuning.json", "identify.tabular-tuning-run/1", (
    F("schema", "str", "", "document id"),
    F("inputs", "list", "", "the model's inputs (the setting columns of tuning.parquet)"),
    F("targets", "object", "", "output -> target value (a count output: the count asked)"),
    F("tolerance_percent", "float", "%", "a continuous output within this of its target is met"),
    F("min_probability", "float", "", "a count target's constraint: P(that count) at least this"),
    F("converged", "bool", "", "the last shot met every target"),
    F("shots_fired", "int", "", "rows of tuning.parquet"),
    F("message", "str", "", "one-line outcome"),
    F("seed", "int", "", "seed of the candidate subset"),
    F("shot_budget", "int", "", "most shots allowed"),
    F("prior_bias_percent", "float", "%", "prior standard deviation of the rig's offset beyond the fit's "
      "uncertainty"),
    F("bias_lengthscale", "float", "", "correlation length of the offset, in units of the inputs' training ranges"),
    F("candidates", "int", "", "settings searched (the lattice inside the training region)"),
    F("rig", "str", "", "the rig (module:function)"),
    F("model_file", "str", "", "the model file (null: a model in memory)"),
    F("model_sha256", "str", "", "SHA-256 of the model file's bytes"),
    F("versions", "object", "", "software versions"),
), "What a table model's tuning run was run for; the shots are tuning.parquet.")

TABULAR_DESIGN = Document("tabular_design", "identify design --json", "identify.tabular-design/1", (
    F("schema", "str", "", "document id"),
    F("feasible", "bool", "", "the fit lies within the tolerance and each count target reaches min_probability"),
    F("settings", "object", "", "input -> the proposed value (inside the training region)"),
    F("targets", "object", "", "output -> target value"),
    F("tolerance_percent", "float", "%", "tolerance of the continuous targets"),
    F("min_probability", "float", "", "constraint of the count targets"),
    F("predicted", "object", "", "the model's prediction at the settings (the columns of `identify predict "
      "--table`)"),
    F("probability_on_target", "float", "", "P(one shot meets every target) by the model"),
    F("candidates", "int", "", "settings searched"),
    F("outside_training_region", "bool", "", "always false: only settings inside are searched"),
    F("message", "str", "", "one-line outcome"),
), "`identify design model.json --target O=V ... --json` with a table model: one JSON object on stdout.")

# ----------------------------------------------------------------------------- printhead rows (issue 32)
NOZZLE_STATES = ("ok", "missing", "weak", "deviated", "satellites")

NOZZLES = Table("nozzles", "nozzles.parquet", "dropvision.nozzles/1", (
    F("nozzle", "int", "", "nozzle index from 0, left to right in the canonical frame (missing nozzles included); "
      "a scan: the label in the file name", nullable=False),
    F("state", "str", "", "one of " + ", ".join(NOZZLE_STATES) + " (the first that applies in that order; "
      "rules in dropvision.analysis.nozzle_row)", nullable=False),
    F("reason", "str", "", "every rule the nozzle met, with the figures compared (empty for ok)", nullable=False),
    F("col_px", "float", "px", "column where the nozzle's trajectory meets the plate (the pitch grid's position)",
      nullable=False),
    F("plate_row_px", "float", "px", "row of the plate's lower edge at that column", nullable=False),
    F("volume_nl", "float", "nl", "main-drop volume, mean over the frames (null: missing)"),
    F("volume_uncertainty_nl", "float", "nl", "its standard uncertainty: the frames' common (edge) uncertainty "
      "and the scatter's standard error in quadrature"),
    F("velocity_m_s", "float", "m/s", "main-drop speed along its trajectory (null for a single delay)"),
    F("velocity_uncertainty_m_s", "float", "m/s", "its standard uncertainty (the straight-line fits)"),
    F("angle_mrad", "float", "mrad", "trajectory angle from the plate normal, + towards increasing canonical "
      "column (IEC 62899-302-3 projected angle); a single delay: from the grid position to the drop"),
    F("angle_uncertainty_mrad", "float", "mrad", "its standard uncertainty"),
    F("satellites", "float", "", "median number of satellites per frame", nullable=False),
    F("satellite_volume_nl", "float", "nl", "mean volume of the satellites where there are some (0: none)"),
    F("n_frames", "int", "", "frames where the nozzle's main drop was measured", nullable=False),
    F("pass", "bool", "", "within the given limits (--volume-tolerance-percent, --velocity-tolerance-percent, "
      "--angle-limit-mrad; against --reference-nozzles where given); null: no limits given", required=False),
    F("pass_reason", "str", "", "every limit the nozzle broke, with the figures compared, and what was not judged "
      "(empty: passed on everything)", required=False),
), "One row per nozzle of a printhead row (`dropvision measure` on a frame of several nozzles under one plate).")

ROW_FRAMES = Table("row_frames", "frames.parquet", "dropvision.row-frames/1", (
    F("file", "str", "", "image file (relative to the sequence folder)", nullable=False),
    F("delay_us", "float", "us", "strobe delay after the firing trigger", nullable=False),
    F("nozzle", "int", "", "nozzle the drop line came from (null: not assigned)"),
    F("volume_nl", "float", "nl", "main-drop volume (attached: below the plate)", nullable=False),
    F("volume_uncertainty_nl", "float", "nl", "its standard uncertainty"),
    F("row_px", "float", "px", "main-drop centroid row (canonical frame)", nullable=False),
    F("col_px", "float", "px", "main-drop centroid column (canonical frame)", nullable=False),
    F("attached", "bool", "", "the main body hangs from the plate", nullable=False),
    F("n_satellites", "int", "", "other bodies on the drop line", nullable=False),
    F("satellite_volume_nl", "float", "nl", "their volume", nullable=False),
), "frames.parquet of a printhead row: one row per frame and drop line (nozzle).")

ROW_BODIES = Table("row_bodies", "bodies.parquet", "dropvision.row-bodies/1", (
    F("file", "str", "", "image file", nullable=False),
    F("delay_us", "float", "us", "strobe delay", nullable=False),
    F("nozzle", "int", "", "nozzle the body came from, by trajectory (null: not assigned)"),
    F("body_class", "str", "", "main_drop, satellite, attached or unassigned", nullable=False),
    F("area_px", "int", "px", "pixels of the body's silhouette", nullable=False),
    F("volume_nl", "float", "nl", "disc-integrated volume (attached: below the plate)", nullable=False),
    F("volume_uncertainty_nl", "float", "nl", "its standard uncertainty"),
    F("row_px", "float", "px", "centroid row (canonical frame)", nullable=False),
    F("col_px", "float", "px", "centroid column (canonical frame)", nullable=False),
), "bodies.parquet of a printhead row: one row per dark body below the plate per frame.")

ROW_SUMMARY = Document("row_summary", "summary.json", "dropvision.row-summary/1", (
    F("schema_version", "str", "", "document id"),
    F("kind", "str", "", "\"printhead-row\""),
    F("layout", "str", "", "row (several nozzles in a frame) or scan (one nozzle per frame, labelled in the file "
      "name: nozzle_03.png)"),
    F("sequence", "str", "", "measured sequence folder"),
    F("n_frames", "int", "", "frames in the sequence", nullable=False),
    F("n_measured", "int", "", "frames measured", nullable=False),
    F("n_nozzles", "int", "", "nozzles of the row, missing ones included (a row: between the first and last live "
      "one; a scan: its labels)", nullable=False),
    F("n_live", "int", "", "nozzles that fired", nullable=False),
    F("state_counts", "object", "", "nozzles per state"),
    F("pitch_um", "float", "um", "nozzle pitch (given, or fitted to the found nozzles; null for a scan)"),
    F("pitch_source", "str", "", "sequence.json, command line --nozzle-pitch-um, or how it was estimated"),
    F("plate_row_px", "float", "px", "row of the plate's lower edge at the frame's centre column"),
    F("plate_slope_mrad", "float", "mrad", "slope of the plate's lower edge in the canonical frame"),
    F("volume_cv", "float", "", "uniformity: CV (SD / mean) of the live nozzles' volumes"),
    F("volume_cv_uncertainty", "float", "", "its standard uncertainty from the nozzles' volume uncertainties"),
    F("velocity_cv", "float", "", "CV of the live nozzles' velocities (null for a single delay)"),
    F("velocity_cv_uncertainty", "float", "", "its standard uncertainty"),
    F("limits", "object", "", "weak_k, weak_floor (fraction of the median), deviated_mrad"),
    F("head_pass", "object", "", "pass/fail of the head (null: no limits given): pass (every nozzle within the "
      "limits), failed_nozzles, limits, limit_sources, reference (the reference table's path or null), not_judged "
      "(quantities not measured, e.g. velocity_m_s of a single delay), reference_alignment (only where the reference's "
      "nozzle numbers differ and were matched by place on the pitch grid)", required=False),
    F("edge_blur_px", "float", "px", "edge blur (Gaussian sigma) of the liquid's edges"),
    F("liquid_level", "float", "", "transmission inside the liquid"),
    F("edge_threshold", "float", "", "transmission level of the edges"),
    F("errors", "list", "", "frames that could not be read"),
    F("notes", "list", "", "what the measurement could not settle"),
    F("orientation", "str", "", "direction the drops travel in the stored images", required=False),
    F("software", "object", "", "versions of Python and of every package the result depends on"),
), "summary.json of a printhead row (`dropvision.analysis.nozzle_row`); the *_source keys of a sequence's summary.json too.")

ROW_INPUTS = Document("row_inputs", "sequence.json (printhead row keys)", "dropvision.io.sequence-row-keys/1", (
    F("nozzle_pitch_um", "float", "um", "nozzle pitch of a row (option --nozzle-pitch-um; default: estimated from "
      "the nozzles found)", required=False),
    F("nozzle_count", "int", "", "the row's number of nozzles (option --nozzle-count): a missing nozzle at an end "
      "of the row is judged where the frame holds the grid on that side only; without it the ends are not judged",
      required=False),
    F("volume_tolerance_percent", "float", "%", "pass/fail: a nozzle's volume within this of its reference nozzle's, "
      "else of the row's median (option --volume-tolerance-percent)", required=False),
    F("velocity_tolerance_percent", "float", "%", "pass/fail: likewise its velocity (option "
      "--velocity-tolerance-percent)", required=False),
    F("angle_limit_mrad", "float", "mrad", "pass/fail: |angle| (with a reference: |angle - reference angle|) within "
      "this (option --angle-limit-mrad)", required=False),
    F("reference_nozzles", "str", "", "a reference head's nozzles.parquet (relative: to the sequence folder; option "
      "--reference-nozzles); needs a limit", required=False),
), "Keys of sequence.json read for a printhead row (issue 32); an option overrides its key.")

TABLES = {t.name: t for t in (FRAMES, BODIES, PER_DELAY, SHOTS, TIMESERIES, DATASET_SUMMARY, DATASET_SHOTS,
                               LIVE_FRAMES, TUNING, TABULAR_PREDICTION, TABULAR_TUNING, NOZZLES, ROW_FRAMES, ROW_BODIES)}
DOCUMENTS = {d.name: d for d in (SUMMARY, SHOTS_SUMMARY, DATASET, MANIFEST, MODEL, OUTPUT_MARKER, WATCH, TUNING_RUN,
                                 PREDICTION, TABULAR_MODEL, TABULAR_TUNING_RUN, TABULAR_DESIGN)}
DOCUMENTS.update({d.name: d for d in (WAVEFORM, TEMPLATE_MODEL)})  # issue 31: waveform templates
DOCUMENTS[ROW_SUMMARY.name] = ROW_SUMMARY  # issue 32: printhead rows
DOCUMENTS[ROW_INPUTS.name] = ROW_INPUTS
TABLES[TEMPLATE_PREDICTION.name] = TEMPLATE_PREDICTION  # issue 31: predictions of a template model
DOCUMENTS.update({d.name: d for d in (TEMPLATE_SETTING_PREDICTION, TABULAR_SETTING_PREDICTION)})


class Quality:
    """Quality codes of the frames table (``quality`` column: ``"ok"`` or codes joined by
    ``"; "``). Short and stable: scripts may group and filter on them; their meaning is in
    :data:`QUALITY_CODES`."""

    OK = "ok"
    SATURATED = "saturated"
    CLIPPED = "clipped_background"
    ILLUMINATION = "illumination_changed"
    LOW_CONTRAST = "low_contrast"
    BLURRED = "blurred"
    NO_NOZZLE = "no_nozzle"
    ATTACHED_LEAVES = "attached_leaves_view"
    DROP_LEAVES = "drop_leaves_view"
    OUT_OF_BAND = "drop_off_band"
    DUST_OVERLAP = "dust_overlap"
    AMBIGUOUS = "ambiguous_separation"
    NO_DROP = "no_drop"
    TAIL = "tail_joined"
    NO_REST_MENISCUS = "no_rest_meniscus"
    PIXEL_SIZE_MISMATCH = "pixel_size_mismatch"
    DELAY_INCONSISTENT = "delay_inconsistent"
    PINCHOFF_UNDEFINED = "pinchoff_undefined"
    NEIGHBOURS = "inconsistent_with_neighbours"
    IMPLAUSIBLE = "implausible_physics"
    NOZZLE_OUT_OF_FOCUS = "nozzle_out_of_focus"
    UNREADABLE = "unreadable"
    NOT_MEASURED = "not_measured"
    NOT_DROP_IMAGE = "not_a_drop_image"


#: Quality code -> explanation (docs/FORMAT.md lists them).
QUALITY_CODES: dict[str, str] = {
    Quality.OK: "every value of the frame is trusted",
    Quality.SATURATED: "too many background pixels at the sensor maximum and their level unknown: volumes not "
                       "trusted",
    Quality.CLIPPED: "background clipped at the sensor maximum; its level was estimated from the nozzle walls "
                     "(or, where their edge is clipped too, the sensor maximum taken as its lower bound) and the "
                     "edges taken below the clip: values kept, their uncertainty widened (a note in the summary "
                     "gives the level)",
    Quality.ILLUMINATION: "the strobe intensity differs from the background model: segmentation not trusted",
    Quality.LOW_CONTRAST: "liquid too bright against the background for sub-pixel edges",
    Quality.BLURRED: "edges blurred beyond the limit (focus or motion)",
    Quality.NO_NOZZLE: "the nozzle could not be located in the frame: its detached drops are measured (each about "
                       "its own axis, the jet's axis their line), what needs the nozzle is NaN (attached volume, "
                       "distance along the axis)",
    Quality.ATTACHED_LEAVES: "the attached liquid leaves the field of view: attached volume incomplete",
    Quality.DROP_LEAVES: "the main drop leaves the field of view: its volume is incomplete",
    Quality.OUT_OF_BAND: "the main drop crosses the edge of the measured column band",
    Quality.DUST_OVERLAP: "the drop overlaps a static speck (dust)",
    Quality.AMBIGUOUS: "attached or detached cannot be decided",
    Quality.NO_DROP: "no detached drop in the field of view",
    Quality.TAIL: "the drop's tail is still joined to it: not used for in-flight values",
    Quality.NO_REST_MENISCUS: "no frame shows the meniscus at rest (first delay after the dead time): "
                              "grown volume and flow unknown",
    Quality.PIXEL_SIZE_MISMATCH: "the given pixel size disagrees with the nozzle's outer diameter beyond the "
                                 "tolerance, or with its inner diameter (the resting meniscus's width at the tip "
                                 "plane): every length and volume is suspect (ratio in summary calibration, the "
                                 "reason in its notes)",
    Quality.DELAY_INCONSISTENT: "the frame's delay contradicts the motion (pinch-off before the dead time, no "
                                "growth during the stroke, drop going back up, implausible velocity): delays "
                                "mislabelled or in the wrong unit",
    Quality.PINCHOFF_UNDEFINED: "the delays do not bracket the pinch-off at the sequence's own step (or too few "
                                "frames): pinch-off unknown",
    Quality.NEIGHBOURS: "volume or drop position disagrees with the neighbouring delays far beyond the "
                        "sequence's own scatter (a frame from another sequence?): left out of the summary",
    Quality.IMPLAUSIBLE: "implausible for the nozzle (drop volume over the limit in nozzle volumes, inner "
                         "diameter >= outer): nozzle dimensions wrong",
    Quality.NOZZLE_OUT_OF_FOCUS: "the nozzle walls are out of focus (the drops are sharper): the tip plane and "
                                 "the liquid next to it are located only to the walls' blur (below a holder's face "
                                 "line: the plane to that line's whole rows, the liquid against the halo's own "
                                 "background); attached and grown volumes kept with that in their uncertainty",
    Quality.UNREADABLE: "the frame could not be read or decoded (its error says why): nothing measured; such a "
                        "frame is listed in summary.json errors, and only the live journal has a row of it",
    Quality.NOT_MEASURED: "shots.parquet: the image could not be measured at all (the reason in its notes and in "
                          "summary.json errors); its values are empty",
    Quality.NOT_DROP_IMAGE: "the image is no backlit drop image (a photograph, a texture, a gradient, a frame shot "
                            "without the backlight): less than half of it is bright background, within 15 % of the "
                            "local background level (the brightest level within a quarter of the frame); a drop "
                            "image is mostly lit background with the nozzle and the liquid dark on it. No number from "
                            "it (its values are NaN, as for untrusted intensities); the summary's notes name the "
                            "frames",
}


# ----------------------------------------------------------------------------- input ranges
#: Accepted physical ranges (inclusive) of the numbers of the inputs: key -> (low, high, unit).
#: Generous for real rigs. sequence.json is read with them (docs/FORMAT.md; a value outside is a
#: ``SequenceError`` naming the key, the value and the range; diameters: also outer > inner when
#: both given) and a model file's scalars are checked against the same upper limits
#: (``identify.model_file.MODEL_RANGES``). The measured quantities at the end bound the columns of a
#: training dataset (``identify.dataset_checks``: a value outside names the column and the likely
#: unit mistake, e.g. velocities in mm/s labelled m/s).
RANGES: dict[str, tuple[float, float, str]] = {
    "pixel_size_um": (0.01, 1000.0, "µm"),
    "nozzle_diameter_um": (1.0, 10000.0, "µm"),
    "delay_us": (-1e6, 1e7, "µs"),
    "frame_rate_hz": (1.0, 1e7, "Hz"),
    "u1_um_per_ms": (1e-6, 1e4, "µm/ms"),
    "u2_um": (1e-6, 1e4, "µm"),
    "u3_um_per_ms": (1e-6, 1e4, "µm/ms"),
    "hold_us": (0.0, 1e6, "µs"),
    "dead_time_us": (0.0, 1e6, "µs"),
    "sample_interval_us": (0.0, 1e4, "µs"),
    "density_kg_m3": (10.0, 1e5, "kg/m³"),
    "viscosity_mPa_s": (1e-3, 1e7, "mPa·s"),
    "surface_tension_mN_m": (0.1, 1e4, "mN/m"),
    # measured (dataset columns): a drop-on-demand jet flies at ~1-10 m/s; its pinch-off comes tens
    # to hundreds of µs after the trigger; its drops are pl to tens of nl (10 µl: a 2.7 mm sphere)
    "jetting_velocity_m_s": (0.0, 100.0, "m/s"),
    "flow_velocity_m_s": (-100.0, 100.0, "m/s"),
    "pinchoff_us": (0.0, 1e4, "µs"),
    "volume_nl": (-1e4, 1e4, "nl"),
}


# ----------------------------------------------------------------------------- checks
_KINDS = {
    "float": lambda k: k in "fiu",
    "int": lambda k: k in "iu" or k == "f",  # Int64 with nulls reads back as float in some paths
    "bool": lambda k: k == "b",
    "str": lambda k: k in "OUS",
    "id": lambda k: k in "iuOUS",
    "object": lambda k: True,
    "list": lambda k: True,
}


def check_table(df, table: Table | str, source) -> None:
    """Check that ``df`` (read from ``source``) has every required column of ``table`` with the
    declared kind, and NaN only where allowed.

    Raises
    ------
    SchemaError
        Naming ``source``, the column and the problem.
    """
    import numpy as np
    import pandas as pd

    table = TABLES[table] if isinstance(table, str) else table
    for col in table.columns:
        if col.name not in df.columns:
            if col.required:
                raise SchemaError(f"{source}: missing column {col.name!r} ({col.meaning}); "
                                  f"expected a {table.schema} table")
            continue
        series = df[col.name]
        kind = series.dtype.kind if not isinstance(series.dtype, pd.CategoricalDtype) else "O"
        if isinstance(series.dtype, pd.BooleanDtype):
            kind = "b"
        elif pd.api.types.is_integer_dtype(series.dtype):
            kind = "i"
        if not _KINDS[col.dtype](kind):
            raise SchemaError(f"{source}: column {col.name!r} has dtype {series.dtype}, expected {col.dtype}"
                              + (f" ({col.unit})" if col.unit else ""))
        if not col.nullable and series.isna().any():
            raise SchemaError(f"{source}: column {col.name!r} has missing values in "
                              f"{int(series.isna().sum())} row(s)")
        if col.dtype == "float" and kind in "fiu":
            values = series.to_numpy(dtype=float, na_value=np.nan)
            if np.isinf(values).any():
                raise SchemaError(f"{source}: column {col.name!r} holds infinite values")


def check_document(doc, document: Document | str, source) -> dict:
    """Check the ``schema`` id (when the document carries one) and the required keys.

    Returns the document. Raises :class:`SchemaError` naming ``source`` and the mismatch.
    """
    document = DOCUMENTS[document] if isinstance(document, str) else document
    if not isinstance(doc, dict):
        raise SchemaError(f"{source}: expected a JSON object ({document.schema}), got {type(doc).__name__}")
    key = "schema_version" if "schema_version" in document.key_names else "schema"
    found = doc.get(key)
    if found is not None and found != document.schema and found not in document.aliases:
        raise SchemaError(f"{source}: schema {found!r} is not {document.schema!r}; it was written by another "
                          "program or another major version")
    missing = [k.name for k in document.keys if k.required and k.name not in ("schema", "schema_version")
               and k.name not in doc]
    if missing:
        raise SchemaError(f"{source}: missing key {missing[0]} (required by {document.schema}"
                          + (f"; also missing: {', '.join(missing[1:])})" if missing[1:] else ")"))
    return doc


def markdown() -> str:
    """The outputs part of docs/FORMAT.md, generated from the declarations."""
    lines = ["<!-- generated from dvcore/schema.py by dvcore.schema.markdown(); do not edit by hand -->", ""]
    for t in TABLES.values():
        lines += [f"### `{t.file}` ({t.schema})", "", t.description, "",
                  "| column | dtype | unit | meaning |", "|---|---|---|---|"]
        lines += [f"| `{c.name}` | {c.dtype}{'' if c.nullable else ', not null'}"
                  f"{'' if c.required else ', optional'} | {c.unit} | {c.meaning} |" for c in t.columns]
        lines.append("")
    for d in DOCUMENTS.values():
        lines += [f"### `{d.file}` ({d.schema})", "", d.description, "",
                  "| key | type | unit | meaning |", "|---|---|---|---|"]
        lines += [f"| `{k.name}` | {k.dtype}{'' if k.required else ', optional'} | {k.unit} | {k.meaning} |"
                  for k in d.keys]
        lines.append("")
    lines += ["### Quality codes (`quality` column)", "", "`ok`, or the codes of a frame joined by `; `.", "",
              "| code | meaning |", "|---|---|"]
    lines += [f"| `{code}` | {text} |" for code, text in QUALITY_CODES.items()]
    return "\n".join(lines) + "\n"
