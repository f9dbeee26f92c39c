"""The Foxglove schema records: the published classes' descriptors, self-contained; integer-ns stamps."""

from __future__ import annotations

import importlib

import pytest
from google.protobuf import descriptor_pool, message_factory
from google.protobuf.descriptor_pb2 import DescriptorProto, FileDescriptorSet

from drivee2e_jax.io import foxglove_schemas as fs


def test_the_written_types_are_foxglove_schemas():
    assert set(fs.CLASSES) == {"foxglove.SceneUpdate", "foxglove.FrameTransform", "foxglove.CompressedImage",
                               "foxglove.PointCloud", "foxglove.Log"}
    for name, cls in fs.CLASSES.items():  # the package's own class, found by name
        short = name.split(".")[1]
        assert cls is getattr(importlib.import_module(f"foxglove_schemas_protobuf.{short}_pb2"), short)


@pytest.mark.parametrize("name", sorted(fs.CLASSES))
def test_descriptor_set_is_complete_ordered_and_decodes(name):
    files = FileDescriptorSet.FromString(fs.file_descriptor_set(name)).file
    names = [f.name for f in files]
    assert len(names) == len(set(names)) and names[-1] == f"foxglove/{name.split('.')[1]}.proto"
    for i, f in enumerate(files):  # every import is in the set, before the file that imports it
        assert set(f.dependency) <= set(names[:i]), (f.name, f.dependency)
    assert "google/protobuf/timestamp.proto" in names
    pool = descriptor_pool.DescriptorPool()  # a reader with only the file: no generated code
    for f in files:
        pool.Add(f)
    built, published = DescriptorProto(), DescriptorProto()
    pool.FindMessageTypeByName(name).CopyToProto(built)
    fs.CLASSES[name].DESCRIPTOR.CopyToProto(published)
    assert built == published
    sample = fs.CLASSES[name]()
    if name == "foxglove.SceneUpdate":
        sample.entities.add(id="e", timestamp=fs.timestamp(4_100_000_000))
    else:
        sample.timestamp.CopyFrom(fs.timestamp(4_100_000_000))
    data = sample.SerializeToString()
    decoded = message_factory.GetMessageClass(pool.FindMessageTypeByName(name)).FromString(data)
    assert decoded.SerializeToString() == data and b"\x08\x04\x10\x80\xc2\xd7\x2f" in data  # 4 s, 1e8 ns


@pytest.mark.parametrize("ns, sec, nsec", [(0, 0, 0), (4_100_000_000, 4, 100_000_000),
                                           (1_999_999_999, 1, 999_999_999), (10**18 + 7, 10**9, 7)])
def test_stamps_from_integer_ns(ns, sec, nsec):
    for stamp in (fs.timestamp(ns), fs.duration(ns)):
        assert (stamp.seconds, stamp.nanos) == (sec, nsec)
        assert fs.to_ns(stamp) == ns
