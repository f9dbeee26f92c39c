"""Export the AD-MLP network to ONNX, to run it outside JAX (ONNX Runtime, TensorRT ...).

``export_ad_mlp(params, model, path)`` writes the graph of ``ad_mlp.ADMLPNet``
built node by node with ``onnx.helper`` from the Flax parameters -- one
``Gemm`` (x @ kernel + bias) per ``nn.Dense``, a ``Relu`` after each hidden
one, then ``Reshape`` to (B, K, 2) and ``CumSum`` over the K waypoints,
exactly the Flax network's layers -- and validates it with
``onnx.checker``. The graph maps a batch of AD-MLP input features
``features`` (B, F) float32 (``ad_mlp.features``: the scaled ego history,
ego state and one-hot command) to ``waypoints`` (B, K, 2) float32, ego
frame, m. The feature computation (and the ego history it needs) stays with
the caller: ``docs/examples/onnx_ad_mlp.py`` does it in numpy as a host
policy, and ``tests/models/test_onnx_export.py`` checks both the graph
(against ``ADMLPNet.apply``) and closed-loop results (against the Flax
policy)::

    from drivee2e_jax.models.base import policy_from_checkpoint
    from drivee2e_jax.models.onnx_export import export_ad_mlp

    pol = policy_from_checkpoint("ad_mlp", "runs/ad_mlp")
    export_ad_mlp(pol.params, pol.model, "ad_mlp.onnx")
    # drivee2e bench --policy docs/examples/onnx_ad_mlp.py:model=ad_mlp.onnx

``onnx`` is an optional dependency (``pip install drivee2e-jax[onnx]``): it
is imported when a graph is exported, never when the package is.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from drivee2e_jax.errors import DriveE2EError
from drivee2e_jax.models import ad_mlp, base

#: ONNX opset and IR version of the exported graph: CumSum needs opset >= 11;
#: 17 / IR 8 load in every onnxruntime >= 1.13 (the newest onnx package's
#: defaults are often ahead of the runtime's).
OPSET = 17
IR_VERSION = 8

#: Names of the graph's input and output.
INPUT = "features"
OUTPUT = "waypoints"

#: Width of ``ad_mlp.features``: the (H, 7) history, the 4 ego values, the 8-way command.
NUM_FEATURES = base.HISTORY_LEN * base.HISTORY_FEATURES + 4 + 8


def _dense_layers(params, model: ad_mlp.ADMLP) -> list[tuple[np.ndarray, np.ndarray]]:
    """[(kernel (in, out), bias (out,))] float32 of ``ADMLPNet``'s Dense layers, in order."""
    tree = params.get("params", params) if hasattr(params, "get") else params
    n = len(model.hidden) + 1
    names = [f"Dense_{i}" for i in range(n)]
    if not hasattr(tree, "keys") or sorted(tree.keys()) != sorted(names):
        got = sorted(tree.keys()) if hasattr(tree, "keys") else type(tree).__name__
        raise DriveE2EError(f"export_ad_mlp: parameters {got} do not fit AD-MLP hidden={tuple(model.hidden)} "
                            f"(expected {names})")
    layers = []
    width = NUM_FEATURES
    for i, name in enumerate(names):
        kernel = np.asarray(tree[name]["kernel"], np.float32)
        bias = np.asarray(tree[name]["bias"], np.float32)
        out = model.hidden[i] if i < len(model.hidden) else 2 * model.num_waypoints
        if kernel.shape != (width, out) or bias.shape != (out,):
            raise DriveE2EError(f"export_ad_mlp: {name} has kernel {kernel.shape} / bias {bias.shape}, "
                                f"expected ({width}, {out}) / ({out},)")
        layers.append((kernel, bias))
        width = out
    return layers


def ad_mlp_graph(params, model: ad_mlp.ADMLP):
    """The ``onnx.ModelProto`` of ``model.net`` with ``params`` (checked by
    ``onnx.checker``). Batch axis ``B`` dynamic; metadata ``drivee2e.*``
    records the model name, K, waypoint_dt, hidden widths and input width."""
    # Optional dependency (the [onnx] extra): imported only when exporting.
    import onnx  # noqa: PLC0415
    from onnx import TensorProto, helper, numpy_helper  # noqa: PLC0415

    layers = _dense_layers(params, model)
    k = int(model.num_waypoints)
    nodes, inits = [], []
    x = INPUT
    for i, (kernel, bias) in enumerate(layers):
        w, b, y = f"dense_{i}/kernel", f"dense_{i}/bias", f"dense_{i}/out"
        inits += [numpy_helper.from_array(kernel, w), numpy_helper.from_array(bias, b)]
        nodes.append(helper.make_node("Gemm", [x, w, b], [y], name=f"dense_{i}"))  # x @ kernel + bias
        x = y
        if i < len(layers) - 1:
            nodes.append(helper.make_node("Relu", [x], [f"relu_{i}"], name=f"relu_{i}"))
            x = f"relu_{i}"
    inits += [numpy_helper.from_array(np.array([-1, k, 2], np.int64), "steps_shape"),
              numpy_helper.from_array(np.array(1, np.int64), "waypoint_axis")]
    nodes.append(helper.make_node("Reshape", [x, "steps_shape"], ["steps"], name="steps"))  # (B, K, 2) displacements
    nodes.append(helper.make_node("CumSum", ["steps", "waypoint_axis"], [OUTPUT], name="cumsum"))
    graph = helper.make_graph(
        nodes, "ad_mlp",
        [helper.make_tensor_value_info(INPUT, TensorProto.FLOAT, ["B", NUM_FEATURES])],
        [helper.make_tensor_value_info(OUTPUT, TensorProto.FLOAT, ["B", k, 2])],
        initializer=inits,
    )
    proto = helper.make_model(graph, producer_name="drivee2e_jax", opset_imports=[helper.make_opsetid("", OPSET)])
    proto.ir_version = IR_VERSION
    meta = {"model": model.name, "num_waypoints": str(k), "waypoint_dt": repr(float(model.waypoint_dt)),
            "hidden": ",".join(str(int(h)) for h in model.hidden), "num_features": str(NUM_FEATURES),
            "history_len": str(base.HISTORY_LEN), "history_dt": repr(float(base.HISTORY_DT))}
    helper.set_model_props(proto, {f"drivee2e.{key}": v for key, v in meta.items()})
    onnx.checker.check_model(proto, full_check=True)
    return proto


def export_ad_mlp(params, model: ad_mlp.ADMLP, path) -> Path:
    """Write ``ad_mlp_graph(params, model)`` to ``path`` (parents created); returns the path.

    Args:
      params: the Flax variables of ``model.net`` (``{"params": {"Dense_i": ...}}``,
        e.g. ``ModelPolicy.params`` or ``checkpoint.load_params(run)``).
      model: the ``ad_mlp.ADMLP`` they belong to (hidden widths, K, waypoint_dt).
    Raises DriveE2EError (one line) when the parameters do not fit the model,
    ImportError naming the extra when ``onnx`` is not installed.
    """
    try:
        import onnx  # noqa: PLC0415 - optional dependency, the [onnx] extra
    except ImportError as e:
        raise ImportError("export_ad_mlp needs the onnx package: pip install 'drivee2e-jax[onnx]'") from e
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    onnx.save_model(ad_mlp_graph(params, model), str(path))
    return path
