"""Labels of shots (issue 30 item 2): file-name tokens, shots.csv, a pattern; conflicts name the file."""

from __future__ import annotations

import pytest

from dropvision.io.labels import (
    LabelError, check_one_series, labels_from_document, labels_from_name, labels_from_pattern, merge_labels, read_label_table,
    varying_labels,
)
from dropvision.io.sequence import SequenceError
from dropvision.analysis.shots import label_columns


def test_the_published_drop_watcher_name():
    assert labels_from_name("images_V1--86_V2-12_V3--30_w1-26_w2-10_w3-31_d1-7_d2-5.jpg") == {
        "V1": -86.0, "V2": 12.0, "V3": -30.0, "w1": 26.0, "w2": 10.0, "w3": 31.0, "d1": 7.0, "d2": 5.0}


@pytest.mark.parametrize("name,labels", [
    ("nozzle_03.png", {"nozzle": 3.0}),
    ("nozzle-03.png", {"nozzle": 3.0}),
    ("gain=2.5_x.tif", {"gain": 2.5}),
    ("V-12.5_w-.5.png", {"V": 12.5, "w": 0.5}),  # decimals
    ("V--0.75.png", {"V": -0.75}),  # the double dash is a minus sign
    ("V-1e3.png", {"V": 1000.0}),
    ("f_0003_01150us.png", {"f": 3.0}),  # 1150us is the delay, not a label
    ("x_12.5us.png", {}),
    ("shot_t-120us_V-3.png", {"V": 3.0}),
    ("images.png", {}),  # tokens without a value are no label
    ("a-b_-3_7_V-.png", {}),
    ("run_A_V-3.png", {"V": 3.0}),
    ("dir/sub_V-4.png", {"V": 4.0}),  # only the last component
    ("V-1_V-1.png", {"V": 1.0}),  # repeated with the same value
])
def test_name_tokens(name, labels):
    assert labels_from_name(name) == labels


def test_a_name_contradicting_itself_is_an_error_naming_the_file():
    with pytest.raises(LabelError, match=r"^a_V-1_V-2.png: label V given twice in the file name \(1 and 2\)$"):
        labels_from_name("a_V-1_V-2.png")
    assert issubclass(LabelError, SequenceError)  # a command line reports it in one line, exit 2


def test_pattern():
    assert labels_from_pattern("run7 at -35.5V.png", r"run(?P<run>\d+) at (?P<V>[-\d.]+)V") == {"run": 7.0, "V": -35.5}
    assert labels_from_pattern("run7.png", r"run(?P<run>\d+)(?: at (?P<V>[-\d.]+)V)?") == {"run": 7.0}
    with pytest.raises(LabelError, match=r"^b.png: the file name does not match the label pattern"):
        labels_from_pattern("b.png", r"run(?P<run>\d+)")
    with pytest.raises(LabelError, match=r"^run_x.png: label run is 'x' by the label pattern, not a number"):
        labels_from_pattern("run_x.png", r"run_(?P<run>\w+)")
    with pytest.raises(LabelError, match="no named group"):
        labels_from_pattern("run7.png", r"run(\d+)")
    with pytest.raises(LabelError, match="not a regular expression"):
        labels_from_pattern("run7.png", r"run(?P<run>\d+")


def test_label_table(tmp_path):
    path = tmp_path / "shots.csv"
    path.write_text("file,V1, nozzle\na.png,-86,3\nsub\\b.png,12.5,\n\n")
    assert read_label_table(path) == {"a.png": {"V1": -86.0, "nozzle": 3.0}, "sub/b.png": {"V1": 12.5}}
    for text, fragment in [
        ("name,V\na.png,1\n", "no 'file' column"),
        ("file,V\na.png,ten\n", "row 2: V is 'ten', not a number"),
        ("file,V\na.png,1\na.png,2\n", "row 3: a.png is listed twice"),
        ("file,V\na.png,1,2\n", "row 2: 3 cells, the header has 2"),
        ("file,2V\na.png,1\n", "column '2V' is not a label name"),
        ("file,V\na.png,nan\n", "row 2: V is 'nan', not a number"),
    ]:
        path.write_text(text)
        with pytest.raises(LabelError, match=fragment) as info:
            read_label_table(path)
        assert str(info.value).startswith(str(path))


def test_sequence_json_shots_list():
    assert labels_from_document([{"file": "a.jpg", "V1": -86, "n": None}, {"file": "b.jpg"}], "s.json") == {
        "a.jpg": {"V1": -86.0}, "b.jpg": {}}
    for entries, fragment in [
        ({"a.jpg": {}}, "'shots' must be a list"),
        (["a.jpg"], "shots[0]: must be an object with a 'file'"),
        ([{"file": "a.jpg", "V": True}], "shots[0]: V is True, not a finite number"),
        ([{"file": "a.jpg", "V": "3"}], "shots[0]: V is '3', not a finite number"),
        ([{"file": "a.jpg", "V": float("nan")}], "not a finite number"),
        ([{"file": "a.jpg", "2V": 1}], "shots[0]: '2V' is not a label name"),
        ([{"file": "a.jpg"}, {"file": "a.jpg"}], "shots[1]: a.jpg is listed twice"),
    ]:
        with pytest.raises(LabelError, match=r"^s.json") as info:
            labels_from_document(entries, "s.json")
        assert fragment in str(info.value)


def test_merge_conflicting_sources_names_the_file():
    labels, origin = merge_labels("x/a.png", [("file name", {"V1": -86.0}), ("shots.csv", {"V1": -86.0, "n": 3.0})])
    assert labels == {"V1": -86.0, "n": 3.0} and origin == {"V1": "file name and shots.csv", "n": "shots.csv"}
    with pytest.raises(LabelError, match=r"^x/a.png: label V1 is -86 by the file name but -90 by the shots.csv$"):
        merge_labels("x/a.png", [("file name", {"V1": -86.0}), ("shots.csv", {"V1": -90.0})])


def test_a_counter_is_not_a_grouping_label():
    assert varying_labels({"img_1.png": {"img": 1.0}, "img_2.png": {"img": 2.0}}) == (["img"], "img")
    assert varying_labels({"a": {"V": 1.0}, "b": {"V": 2.0}, "c": {"V": 1.0}}) == (["V"], None)
    assert varying_labels({"a": {"V": 1.0, "w": 1.0}, "b": {"V": 2.0, "w": 2.0}}) == (["V", "w"], None)
    assert varying_labels({"a": {"V": 1.0}, "b": {}}) == (["V"], None)  # a missing label is a value too
    assert varying_labels({"a": {}, "b": {}}) == ([], None)
    check_one_series(["img_0001.png", "img_0002.png", "img_0003.png"], "stack")
    check_one_series(["a.png", "b.png"], "stack")
    with pytest.raises(LabelError, match=r"^w: the file names carry different labels \(V2, w1 differ, e.g. "
                                         r"a_V2-12_w1-3.png and b_V2-13_w1-4.png\): .*never blended"):
        check_one_series(["a_V2-12_w1-3.png", "b_V2-13_w1-4.png"], "w")


def test_label_columns_never_replace_a_declared_column():
    assert label_columns(["V1", "quality", "file"]) == {"V1": "V1", "quality": "label_quality", "file": "label_file"}
