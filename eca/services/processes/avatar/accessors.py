"""Accessor data as numpy arrays: buffers loaded once (the GLB BIN chunk, a data URI or a file beside the model),
elements read through their view's byteStride, integers normalised where the accessor says so, sparse
substitutions applied, and floats checked finite.

build_document has already checked each accessor against its view and each view against its buffer's stated
length; here a buffer's actual bytes are checked against that stated length when it is loaded, and each read
checks its element count against the caller's limit before anything is allocated.
"""

from __future__ import annotations

import numpy as np
import pygltflib as gl

from eca.services.processes.avatar.container import Container, read_uri
from eca.services.processes.avatar.document import COMPONENT_DTYPES, accessor_layout
from eca.services.processes.avatar.errors import AvatarError


class AccessorReader:
    """Reads a checked document's accessors; buffers are loaded on first use."""

    def __init__(self, container: Container, document: gl.GLTF2) -> None:
        self.container = container
        self.document = document
        self._buffers: dict[int, memoryview] = {}

    def buffer(self, index: int) -> memoryview:
        """Buffer `index`'s bytes, exactly its stated byteLength."""
        found = self._buffers.get(index)
        if found is not None:
            return found
        buffer = self.document.buffers[index]
        where = f"buffers[{index}]"
        length = int(buffer.byteLength)
        if buffer.uri is None:
            chunk = self.container.bin_chunk
            if not self.container.is_glb or index != 0:
                raise AvatarError(f"{where} has no uri (only a GLB's buffers[0] may use its BIN chunk)")
            if chunk is None:
                raise AvatarError(f"{where} has no uri, and the GLB has no BIN chunk")
            if len(chunk) < length:
                raise AvatarError(f"{where}.byteLength says {length} bytes, the GLB's BIN chunk holds {len(chunk)}")
            data = chunk[:length]
        else:
            raw = read_uri(self.container, buffer.uri, where, length, prefix=True)
            if len(raw) < length:
                raise AvatarError(f"{where}.byteLength says {length} bytes, its uri holds {len(raw)}")
            data = memoryview(raw)[:length]
        self._buffers[index] = data
        return data

    def view(self, index: int) -> memoryview:
        """Buffer view `index`'s bytes."""
        view = self.document.bufferViews[index]
        start = int(view.byteOffset or 0)
        return self.buffer(view.buffer)[start:start + int(view.byteLength)]

    def count(self, index: int) -> int:
        return int(self.document.accessors[index].count)

    def read(self, index: int, where: str, types: tuple[str, ...], max_count: int, limit_name: str,
             as_float: bool = True) -> np.ndarray:
        """Accessor `index` (used at `where`) as a (count, components) array: float32 (integers normalised when
        the accessor says `normalized`) or, with `as_float` False, its integer components as int64."""
        accessor = self.document.accessors[index]
        label = f"accessors[{index}] ({where})"
        if accessor.type not in types:
            raise AvatarError(f"{label} is {accessor.type}, expected {' or '.join(types)}")
        count = int(accessor.count)
        if count > max_count:
            raise AvatarError(f"{label} has {count} elements, more than the limit of {max_count} ({limit_name})")
        layout = accessor_layout(accessor, self.document.bufferViews)
        if accessor.type in (gl.MAT2, gl.MAT3) and layout.dtype.itemsize < 4:
            raise AvatarError(f"{label}: padded {accessor.type} columns of {layout.dtype.itemsize}-byte "
                              "components are not read")
        if not as_float and layout.dtype.kind == "f":
            raise AvatarError(f"{label} must hold integers, it holds floats")
        shape = (count, layout.components)
        if accessor.bufferView is None or count == 0:
            data = np.zeros(shape, dtype=layout.dtype)
        else:
            raw = self.view(accessor.bufferView)
            strided = np.ndarray(shape, dtype=layout.dtype, buffer=raw, offset=int(accessor.byteOffset or 0),
                                 strides=(layout.stride, layout.dtype.itemsize))
            data = np.array(strided)  # a contiguous, writable copy
        if accessor.sparse is not None:
            self._apply_sparse(accessor, data, label)
        if not as_float:
            return data.astype(np.int64)
        if layout.dtype.kind == "f":
            values = data.astype(np.float32, copy=False)
            if not np.isfinite(values).all():
                raise AvatarError(f"{label} holds non-finite numbers (NaN or infinity)")
            return values
        if accessor.normalized:
            scale = float(np.iinfo(layout.dtype).max)
            unit: np.ndarray = np.maximum(data.astype(np.float32) / np.float32(scale), np.float32(-1.0))
            return unit
        return data.astype(np.float32)

    def _apply_sparse(self, accessor: gl.Accessor, data: np.ndarray, label: str) -> None:
        sparse = accessor.sparse
        assert sparse is not None
        n = int(sparse.count)
        index_dtype = COMPONENT_DTYPES[sparse.indices.componentType]
        index_raw = self.view(sparse.indices.bufferView)
        indices = np.frombuffer(index_raw, dtype=index_dtype, count=n, offset=int(sparse.indices.byteOffset or 0))
        if n and int(indices.max()) >= data.shape[0]:
            raise AvatarError(f"{label}: a sparse index {int(indices.max())} is past its {data.shape[0]} elements")
        value_raw = self.view(sparse.values.bufferView)
        values = np.frombuffer(value_raw, dtype=data.dtype, count=n * data.shape[1],
                               offset=int(sparse.values.byteOffset or 0))
        data[indices.astype(np.int64)] = values.reshape(n, data.shape[1])
