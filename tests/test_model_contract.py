"""The loader refuses every breach of the model contract with one clear ModelContractError."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import onnx
import pytest
from onnx import helper

from runtime.model import METADATA_KEY, ModelContractError, ModelInputError, load_model
from runtime.onnx_wire import summarize
from tests.onnx_fixtures import export, fit_model


@pytest.fixture(scope="module")
def good_path(tmp_path_factory):
    return export(fit_model("linear"), tmp_path_factory.mktemp("good"))


@pytest.fixture
def proto(good_path):
    return onnx.load(str(good_path))


def _meta(proto) -> dict:
    return json.loads(next(p.value for p in proto.metadata_props if p.key == METADATA_KEY))


def _with_meta(proto, meta: dict):
    for p in proto.metadata_props:
        if p.key == METADATA_KEY:
            p.value = json.dumps(meta)
    return proto


def _save(proto, tmp_path, name="bad.onnx"):
    path = tmp_path / name
    path.write_bytes(proto.SerializeToString())
    return path


def _refused(path, match: str, **kw):
    with pytest.raises(ModelContractError, match=match) as info:
        load_model(path, **kw)
    assert str(path) in str(info.value) and "\n" not in str(info.value)


def test_good_model_loads_and_runs(good_path):
    model = load_model(good_path)
    assert len(model.model_id) == 12 and model.path == good_path
    labels, scores = model.run(np.zeros((3, model.meta.T, model.meta.n_channels)))
    assert labels.dtype == np.int64 and labels.shape == (3,)
    assert scores.dtype == np.float32 and scores.shape == (3, model.meta.n_classes)
    labels, _ = model.run(np.zeros((model.meta.T, model.meta.n_channels)))  # one window without batch axis
    assert labels.shape == (1,)


def test_unreadable_empty_truncated_garbage(good_path, tmp_path):
    _refused(tmp_path / "missing.onnx", "cannot read")
    (tmp_path / "empty.onnx").write_bytes(b"")
    _refused(tmp_path / "empty.onnx", "empty file")
    data = good_path.read_bytes()
    for cut in (len(data) // 2, len(data) - 3, 10):
        (tmp_path / "cut.onnx").write_bytes(data[:cut])
        _refused(tmp_path / "cut.onnx", "truncated|cannot load")
    (tmp_path / "text.onnx").write_text("hello, I am not a model\n" * 10)
    _refused(tmp_path / "text.onnx", "not an ONNX model|cannot load")
    (tmp_path / "rand.onnx").write_bytes(np.random.default_rng(0).bytes(4000))
    _refused(tmp_path / "rand.onnx", "not an ONNX model|cannot load")


def test_size_limit(good_path):
    _refused(good_path, "exceeds the limit", max_bytes=100)


def test_missing_or_broken_metadata(proto, tmp_path):
    del proto.metadata_props[:]
    _refused(_save(proto, tmp_path), "no 'handover' metadata")
    proto.metadata_props.add(key=METADATA_KEY, value="{not json")
    _refused(_save(proto, tmp_path), "not valid JSON")


@pytest.mark.parametrize(
    ("change", "match"),
    [
        (lambda m: m.pop("classes"), "lacks classes"),
        (lambda m: m.update(schema_version=2), "schema_version"),
        (lambda m: m.update(n_channels=17), r"n_channels=17 != sum\(pad_sizes\)"),
        (lambda m: m.update(pad_sizes=[6, 10, 1], n_channels=17), "pad_sizes"),
        (lambda m: m.update(T=13), r"shape .* metadata says \[N, T=13"),
        (lambda m: m.update(W=12), "fewer than W=12"),
        (lambda m: m.update(T=-3), r"T=-3 must be a window of at least 2 frames \(the trained window length"),
        (lambda m: m.update(T=0), r"T=0 must be a window of at least 2 frames"),
        (lambda m: m.update(classes=["a", "b", "c"]), r"'scores' .* \[N, 3\]"),
        (lambda m: m.update(classes=["a", "a", "b", "c"]), "distinct"),
        (lambda m: m.update(dormant_class="idle"), "dormant_class"),
        (lambda m: m.update(trigger={"fraction": 1.5}), "trigger.fraction"),
        (lambda m: m.update(sample_rate_hz=-1), "sample_rate_hz"),
        (lambda m: m.update(sample_rate_hz=float("nan")), "sample_rate_hz"),
        (lambda m: m.update(sample_rate_hz=1e300), "sample_rate_hz must be between"),
        (lambda m: m.update(sample_rate_hz=1e-3), "sample_rate_hz must be between"),
        (lambda m: m.update(fullscale=1e308), "fullscale 1e[+]308 is more than the pads can report"),
        (lambda m: m.update(fullscale=-1e308), "fullscale must be a positive number"),
        (lambda m: m.update(fullscale=float("nan")), "fullscale must be a positive number"),
        (lambda m: m.update(fullscale=0), "fullscale must be a positive number"),
        (lambda m: m.update(fullscale=1e-320), r"fullscale 9.99989e-321 is below 1, not a 12-bit pad's full scale"),
        (lambda m: m["trigger"].update(kind="onset", change=5), "trigger.change"),
        (lambda m: m["trigger"].update(kind="onset", change=float("nan")), "trigger.change"),
        (lambda m: m["trigger"].update(kind="onset", change="abc"), "trigger.change"),
        (lambda m: m["trigger"].update(kind="bogus"), "trigger.kind"),
        (lambda m: m["trigger"].update(kind="onset", pre_frames=10**9), "trigger.pre_frames"),
        (lambda m: m["trigger"].update(kind="onset", floor=-1), "trigger.floor"),
        (lambda m: m["trigger"].update(kind="onset", floor=0), "trigger.floor"),
        (lambda m: m["trigger"].update(kind="onset", settle_change=float("nan")), "trigger.settle_change"),
        (lambda m: m["trigger"].update(kind="onset", contact=float("inf")), "trigger.contact"),
        (lambda m: m["training"].pop("data_fingerprint"), "training lacks data_fingerprint"),
        (lambda m: m.update(T="15"), "T must be an integer"),
        (lambda m: m.update(classes="push"), "classes must be a list"),
        (lambda m: m.update(classes=[1, 2, 3, 4]), "classes must be names"),
        (lambda m: m.update(pads="13"), "pads must be a list"),
        (lambda m: m.update(K=3, W=2), "metadata K=3, but the graph's codebook has 6 words"),
        (lambda m: m.update(W=4), "metadata W=4, but the graph's longest codeword window is 5"),
        (lambda m: m["features"].update(windows=[3, 5]), r"features.windows \[3, 5\]"),
    ],
)
def test_inconsistent_metadata(proto, tmp_path, change, match):
    meta = _meta(proto)
    change(meta)
    _refused(_save(_with_meta(proto, meta), tmp_path), match)


def test_wrong_input_and_outputs(proto, tmp_path):
    bad = onnx.ModelProto()
    bad.CopyFrom(proto)
    bad.graph.input[0].name = "x"
    for node in bad.graph.node:
        node.input[:] = ["x" if i == "frames" else i for i in node.input]
    _refused(_save(bad, tmp_path), "inputs \\['x'\\]")
    bad.CopyFrom(proto)
    bad.graph.output[0].name = "label_renamed"
    for node in bad.graph.node:
        node.output[:] = ["label_renamed" if o == "label" else o for o in node.output]
    _refused(_save(bad, tmp_path), "outputs")
    bad.CopyFrom(proto)
    cast = helper.make_node("Cast", ["scores_f"], ["scores"], to=onnx.TensorProto.DOUBLE)
    for node in bad.graph.node:
        node.output[:] = ["scores_f" if o == "scores" else o for o in node.output]
    bad.graph.node.append(cast)
    bad.graph.output[1].type.tensor_type.elem_type = onnx.TensorProto.DOUBLE
    _refused(_save(bad, tmp_path), "tensor\\(double\\)")


def test_non_standard_domain(proto, tmp_path):
    proto.graph.node.append(helper.make_node("Relu", ["scores"], ["extra"], domain="com.example"))
    proto.opset_import.append(helper.make_opsetid("com.example", 1))
    _refused(_save(proto, tmp_path), "non-standard operator domain.*com.example")


def test_external_data(proto, tmp_path):
    from onnx.external_data_helper import convert_model_to_external_data

    convert_model_to_external_data(proto, all_tensors_to_one_file=True, location="weights.bin", size_threshold=0)
    onnx.save_model(proto, str(tmp_path / "ext.onnx"))
    _refused(tmp_path / "ext.onnx", "external data")


def test_wire_reader_agrees_with_onnx(good_path, proto):
    wire = summarize(good_path.read_bytes())
    assert wire.n_nodes == len(proto.graph.node)
    assert wire.opset_domains == {o.domain for o in proto.opset_import}
    assert wire.node_domains == {n.domain for n in proto.graph.node}
    assert not wire.external_data
    assert wire.initializer_dims == {i.name: tuple(i.dims) for i in proto.graph.initializer}
    assert wire.initializer_dims[next(n for n in wire.initializer_dims if n.startswith("codeword_kernel"))] == (6, 1, 5, 1)


def test_fixed_batch_size_is_refused_clearly(proto, tmp_path):
    proto.graph.input[0].type.tensor_type.shape.dim[0].dim_value = 2
    _refused(_save(proto, tmp_path), "fixed batch size of 2; the contract needs a dynamic")


def _local_function(inner_domain: str = ""):
    return helper.make_function("local.fns", "Twice", ["x"], ["y"],
                                [helper.make_node("Add", ["x", "x"], ["y"], domain=inner_domain)],
                                [helper.make_opsetid(inner_domain, 17 if inner_domain == "" else 1)])


def test_local_functions_are_read_and_their_domains_checked(proto, tmp_path):
    proto.functions.append(_local_function())
    proto.graph.node.append(helper.make_node("Twice", ["scores"], ["twice"], domain="local.fns"))
    proto.opset_import.append(helper.make_opsetid("local.fns", 1))
    wire = summarize(proto.SerializeToString())
    assert wire.n_nodes == len(proto.graph.node) + 1 and "local.fns" in wire.node_domains
    # refused for what it is (a non-standard domain), not as a truncated file
    _refused(_save(proto, tmp_path), "non-standard operator domain.*local.fns")
    inner = onnx.ModelProto()
    inner.CopyFrom(proto)
    inner.functions[0].CopyFrom(_local_function("com.example"))
    assert "com.example" in summarize(inner.SerializeToString()).node_domains


def test_external_data_in_sparse_attributes(proto):
    values = onnx.numpy_helper.from_array(np.array([1.0], dtype=np.float32), "v")
    indices = onnx.numpy_helper.from_array(np.array([0], dtype=np.int64), "i")
    values.ClearField("raw_data")
    values.data_location = onnx.TensorProto.EXTERNAL
    values.external_data.add(key="location", value="weights.bin")
    sparse = helper.make_sparse_tensor(values, indices, [4])
    proto.graph.node.append(helper.make_node("Constant", [], ["c"], sparse_value=sparse))
    assert summarize(proto.SerializeToString()).external_data
    proto.graph.node[-1].attribute[0].sparse_tensor.values.data_location = onnx.TensorProto.DEFAULT
    del proto.graph.node[-1].attribute[0].sparse_tensor.values.external_data[:]
    assert not summarize(proto.SerializeToString()).external_data


def test_run_trusted_matches_run(good_path):
    model = load_model(good_path)
    x = np.random.default_rng(0).integers(0, 4096, (5, model.meta.T, model.meta.n_channels)).astype(np.float32)
    labels, scores = model.run(x)
    for trusted in (model.run_trusted(x), model.run(x, check=False)):
        np.testing.assert_array_equal(trusted[0], labels)
        np.testing.assert_array_equal(trusted[1], scores)


def test_input_refused_at_the_boundary(good_path):
    model = load_model(good_path)
    shape = (2, model.meta.T, model.meta.n_channels)
    for bad in (np.nan, np.inf, -np.inf):
        x = np.zeros(shape, dtype=np.float32)
        x[1, 3, 2] = bad
        with pytest.raises(ModelInputError, match="NaN or infinity"):
            model.run(x)
    with pytest.raises(ModelInputError, match="expects frames"):
        model.run(np.zeros((2, model.meta.T + 1, model.meta.n_channels)))
    with pytest.raises(ModelInputError, match="expects frames"):
        model.run(np.zeros((0, model.meta.T, model.meta.n_channels)))


def test_runtime_never_imports_onnx_or_sklearn(good_path):
    code = (
        "import sys, runtime.model as m; x = m.load_model(sys.argv[1]); x.run(x.check_input("
        "__import__('numpy').zeros((1, x.meta.T, x.meta.n_channels))));"
        "bad = [k for k in ('onnx', 'sklearn', 'matplotlib') if k in sys.modules]; print(bad)"
    )
    out = subprocess.run([sys.executable, "-c", code, str(good_path)], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]"


def test_inspect_card(good_path, tmp_path, capsys):
    from runtime.cli import main as handover

    assert handover(["inspect", str(good_path)]) == 0
    out = capsys.readouterr().out
    assert "detects: bump, hold, pull, push" in out and "nodes" in out and "synthetic-test" in out
    assert "threshold trigger at " in out  # no recorded kind: cut by the threshold, served with it
    from runtime.commands.inspect_cli import _features

    level = _features({"K": 10, "W": 7, "per_pad": True, "pads": [1, 3], "level_features": True})
    assert level.endswith("one histogram per pad (2), plus each pad's mean level and slope")  # not hidden
    assert handover(["inspect", str(good_path), "--json"]) == 0
    card = json.loads(capsys.readouterr().out)
    assert card["T"] == 12 and card["graph"]["n_nodes"] > 10 and card["pads"] == [1, 3]
    (tmp_path / "bad.onnx").write_bytes(b"\x00" * 10)
    assert handover(["inspect", str(tmp_path / "bad.onnx")]) == 2
    assert capsys.readouterr().err.startswith("handover inspect: model ")


def test_inspect_user_errors_exit_2_and_name_what_was_given(tmp_path, capsys):
    """inspect exited 1 where verify exits 2, and called a recording `not an ONNX model or truncated
    (unsupported wire type 3 ...)`."""
    from firmware_io.recordings.recording import Recording
    from runtime.cli import main as handover
    from tests.protocol_standin import standin_recordings

    assert handover(["inspect", str(tmp_path / "modle.onnx")]) == 2
    assert "cannot read" in capsys.readouterr().err
    rec: Recording = standin_recordings(n_subjects=1, runs=1)[0]
    path = tmp_path / "subject_s1.hrec"
    rec.save(path)
    assert handover(["inspect", str(path)]) == 2
    err = capsys.readouterr().err.strip()
    assert err == f"handover inspect: model {path}: this is a recording (a zip archive such as .hrec), not a model; " \
                  "give a .onnx model", err


@pytest.mark.parametrize("extra", [{"features": [1, 2]}, {"features": {"families": 5}},
                                   {"features": {"families": [{"x": 1}]}}, {"graph": [1]}, {"svm": "rbf"},
                                   {"features": {"families": "hand"}}])
def test_inspect_card_of_odd_optional_metadata_is_a_card_not_a_traceback(proto, tmp_path, capsys, extra):
    """The loader accepts any optional key; ``inspect`` died of TypeError/AttributeError on
    ``features`` or ``graph`` of the wrong type (a hand-edited or hostile model file)."""
    from runtime.cli import main as handover

    meta = _meta(proto)
    meta.update(extra)
    path = _save(_with_meta(proto, meta), tmp_path)
    assert handover(["inspect", str(path)]) == 0
    assert "detects:" in capsys.readouterr().out


@pytest.mark.parametrize("stored", ["raw_data", "float_data"])
def test_a_nan_constant_is_refused_in_one_line_and_an_infinity_is_not_a_wire_problem(proto, tmp_path, stored):
    """One NaN weight passed every check before (the attacker's find); +-inf can be deliberate
    (the padded median's offsets), so only NaN is refused at load."""
    from onnx import numpy_helper

    target = next(i for i in proto.graph.initializer if i.data_type == onnx.TensorProto.FLOAT and np.prod(i.dims) > 1)
    values = numpy_helper.to_array(target).copy()
    values.flat[len(values.flat) // 2] = np.inf
    target.CopyFrom(numpy_helper.from_array(values, target.name))
    assert summarize(proto.SerializeToString()).nan_initializers == []
    values.flat[0] = np.nan
    replaced = numpy_helper.from_array(values, target.name)
    if stored == "float_data":
        replaced.ClearField("raw_data")
        replaced.float_data.extend(values.ravel().tolist())
    target.CopyFrom(replaced)
    assert summarize(proto.SerializeToString()).nan_initializers == [target.name]
    _refused(_save(proto, tmp_path), f"constant\\(s\\) {target.name} hold NaN.*export it again")


def _with_nan_carrier(proto, carrier: str):
    """The model with one extra constant holding NaN the way ``carrier`` says; returns its name."""
    from onnx import TensorProto, numpy_helper

    nan = np.array([np.nan, 1.0], dtype=np.float32)
    graph = proto.graph
    if carrier in ("float16 raw", "float16 int32_data", "bfloat16"):
        kind = TensorProto.BFLOAT16 if carrier == "bfloat16" else TensorProto.FLOAT16
        tensor = (numpy_helper.from_array(nan.astype(np.float16), "c") if carrier == "float16 raw"
                  else helper.make_tensor("c", kind, [2], nan.tolist()))
        graph.initializer.append(tensor)
    elif carrier.startswith("complex"):
        kind = np.complex64 if carrier == "complex64" else np.complex128
        graph.initializer.append(numpy_helper.from_array(np.array([1 + 2j, complex(0, np.nan)], dtype=kind), "c"))
    elif carrier.startswith("float8"):
        kind = {"float8 e4m3fn": TensorProto.FLOAT8E4M3FN, "float8 e5m2": TensorProto.FLOAT8E5M2,
                "float8 e4m3fnuz": TensorProto.FLOAT8E4M3FNUZ}[carrier]
        graph.initializer.append(helper.make_tensor("c", kind, [2], [1.0, float("nan")]))
    elif carrier == "sparse initializer":
        graph.sparse_initializer.append(helper.make_sparse_tensor(
            numpy_helper.from_array(nan[:1], "c"), numpy_helper.from_array(np.array([0], np.int64), "ci"), [4]))
    elif carrier.startswith("Constant value"):
        attr = {"Constant value": {"value": numpy_helper.from_array(nan, "v")},
                "Constant value_float": {"value_float": float("nan")},
                "Constant value_floats": {"value_floats": nan.tolist()}}[carrier]
        graph.node.insert(0, helper.make_node("Constant", [], ["c"], **attr))
    elif carrier == "Constant in a subgraph":
        branches = [helper.make_graph([helper.make_node("Constant", [], [out], value_float=value)], out, [],
                                      [helper.make_tensor_value_info(out, TensorProto.FLOAT, [])])
                    for out, value in (("c", float("nan")), ("d", 1.0))]
        graph.initializer.append(numpy_helper.from_array(np.array(True), "cond"))
        graph.node.append(helper.make_node("If", ["cond"], ["unused"], then_branch=branches[0], else_branch=branches[1]))
    return "c"


@pytest.mark.parametrize("carrier", ["float16 raw", "float16 int32_data", "bfloat16", "complex64", "complex128",
                                     "float8 e4m3fn", "float8 e5m2", "float8 e4m3fnuz", "sparse initializer",
                                     "Constant value", "Constant value_float", "Constant value_floats",
                                     "Constant in a subgraph"])
def test_a_nan_in_any_float_constant_is_refused(proto, tmp_path, carrier):
    """Float initializers alone were scanned: NaN in float16, complex, float8, a sparse initializer or a
    Constant node (subgraphs too) loaded silently."""
    name = _with_nan_carrier(proto, carrier)
    assert summarize(proto.SerializeToString()).nan_initializers == [name]
    _refused(_save(proto, tmp_path), f"constant\\(s\\) {name} hold NaN")


def test_a_nan_attribute_of_another_operator_is_not_a_damaged_constant(proto):
    """Operators other than Constant may mean NaN (ai.onnx.ml Imputer's replaced value, TreeEnsemble's
    set separators): the wire scan leaves them to the model contract."""
    proto.graph.node.append(helper.make_node("Imputer", ["x"], ["y"], domain="ai.onnx.ml",
                                             imputed_value_floats=[0.0], replaced_value_float=float("nan")))
    assert summarize(proto.SerializeToString()).nan_initializers == []


@pytest.mark.parametrize("where", ["features", "training"])
@pytest.mark.parametrize("value", ["false", "no", None, 0, [], {"a": 1}])
def test_inspect_level_features_only_when_recorded_true(tmp_path, capsys, where, value):
    """``"level_features": "false"`` (a string) was truthy: the card claimed level features the model lacks."""
    from runtime.cli import main as handover
    from tests.tiny_models import tiny_model_bytes

    m = onnx.load_from_string(tiny_model_bytes())
    meta = json.loads(m.metadata_props[0].value)
    meta.setdefault(where, {})["level_features"] = value
    m.metadata_props[0].value = json.dumps(meta)
    path = tmp_path / "m.onnx"
    onnx.save(m, str(path))
    assert handover(["inspect", str(path)]) == 0
    assert "mean level and slope" not in capsys.readouterr().out
    assert handover(["inspect", str(path), "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["level_features"] is False


@pytest.mark.parametrize("kind", ["FLOAT8E4M3FN", "FLOAT8E4M3FNUZ", "FLOAT8E5M2", "FLOAT8E5M2FNUZ"])
def test_the_largest_and_infinite_float8_values_are_not_nan(proto, kind):
    """The float8 scan reads NaN bit patterns only: e4m3fn's +-448 (0x7E, 0xFE), e5m2's infinity (0x7C) pass."""
    from onnx import TensorProto

    values = {"FLOAT8E4M3FN": [448.0, -448.0, 0.0], "FLOAT8E4M3FNUZ": [240.0, -240.0, 0.0],
              "FLOAT8E5M2": [float("inf"), float("-inf"), 57344.0], "FLOAT8E5M2FNUZ": [57344.0, -57344.0, 0.0]}[kind]
    proto.graph.initializer.append(helper.make_tensor("c", getattr(TensorProto, kind), [3], values))
    from onnx import numpy_helper

    proto.graph.initializer.append(numpy_helper.from_array(np.array([1 - 2j, complex(np.inf, 0)], np.complex64), "z"))
    assert summarize(proto.SerializeToString()).nan_initializers == []
