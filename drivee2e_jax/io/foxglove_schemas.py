"""Foxglove's published message schemas, as Foxglove publishes them (host side).

The ``foxglove.*`` messages of ``io.mcap_export`` are the protobuf classes of
the ``foxglove-schemas-protobuf`` package, and each MCAP schema record carries
the ``FileDescriptorSet`` of that class (``encoding "protobuf"``), so nothing
here is copied by hand: a field Foxglove adds or renames reaches the file with
the package.

Why this package and not ``foxglove-sdk`` (both are Foxglove's, generated from
one schema source in the foxglove/foxglove-sdk repository):

* ``foxglove-schemas-protobuf`` (0.4.0, MIT): a 0.1 MB pure-Python wheel whose
  only dependency is ``protobuf``, which the project already pulls in through
  ``orbax-checkpoint``. Its classes encode AND decode, so the tests parse every
  written message with the official class of its channel's schema. Protobuf is
  the encoding Foxglove's own SDKs write, and the Foxglove app decodes it from
  the descriptors in the file with no setup.
* ``foxglove-sdk`` (0.30.3): a 19 MB wheel (53 MB installed) with a compiled
  Rust extension; its message classes are immutable and encode only (no
  decoding to check a file against), and its MCAP writer logs through a global
  context and owns the file, where the export writes through ``mcap.Writer``
  into ``files.atomic_write``'s temporary file.

Time: Foxglove's protobuf schemas stamp with ``google.protobuf.Timestamp`` /
``Duration``; :func:`timestamp` and :func:`duration` fill them from integer
nanoseconds, never from floats.
"""

from __future__ import annotations

import functools

from foxglove_schemas_protobuf.CompressedImage_pb2 import CompressedImage
from foxglove_schemas_protobuf.FrameTransform_pb2 import FrameTransform
from foxglove_schemas_protobuf.Log_pb2 import Log
from foxglove_schemas_protobuf.PointCloud_pb2 import PointCloud
from foxglove_schemas_protobuf.SceneUpdate_pb2 import SceneUpdate
from google.protobuf.descriptor import FileDescriptor
from google.protobuf.descriptor_pb2 import FileDescriptorProto, FileDescriptorSet
from google.protobuf.duration_pb2 import Duration
from google.protobuf.timestamp_pb2 import Timestamp

#: MCAP schema / message encoding of every ``foxglove.*`` channel.
ENCODING = "protobuf"
NS_PER_S = 1_000_000_000

#: Schema name (the protobuf full name) -> the official class, for every Foxglove type the export writes.
CLASSES = {cls.DESCRIPTOR.full_name: cls for cls in (SceneUpdate, FrameTransform, CompressedImage, PointCloud, Log)}


def _files_in_dependency_order(fd: FileDescriptor, seen: set[str]) -> list[FileDescriptor]:
    """``fd`` and every file it imports, transitively; each file after its imports, none twice."""
    if fd.name in seen:
        return []
    seen.add(fd.name)
    out = []
    for dep in fd.dependencies:
        out += _files_in_dependency_order(dep, seen)
    return out + [fd]


@functools.cache
def file_descriptor_set(schema_name: str) -> bytes:
    """The serialized ``FileDescriptorSet`` of ``CLASSES[schema_name]``: its .proto
    file and all it imports (``google/protobuf/timestamp.proto`` included), the
    schema data Foxglove and ``mcap`` readers decode a ``protobuf`` channel with."""
    files = []
    for fd in _files_in_dependency_order(CLASSES[schema_name].DESCRIPTOR.file, set()):
        proto = FileDescriptorProto()
        fd.CopyToProto(proto)
        files.append(proto)
    return FileDescriptorSet(file=files).SerializeToString()


def timestamp(ns: int) -> Timestamp:
    """``google.protobuf.Timestamp`` of ``ns`` integer nanoseconds (>= 0) since the file's epoch."""
    return Timestamp(seconds=ns // NS_PER_S, nanos=ns % NS_PER_S)


def duration(ns: int) -> Duration:
    """``google.protobuf.Duration`` of ``ns`` integer nanoseconds (>= 0)."""
    return Duration(seconds=ns // NS_PER_S, nanos=ns % NS_PER_S)


def to_ns(stamp: Timestamp | Duration) -> int:
    """Integer nanoseconds of a Timestamp / Duration (the inverse of :func:`timestamp`)."""
    return stamp.seconds * NS_PER_S + stamp.nanos
