"""Mesh files of URDF visuals: a COLLADA file whose node binds a material the file lacks (a
Blender export whose texture was renamed: one of example-robot-data's ANYmal feet) read as
holding no triangles, so the URDF could not be drawn."""

from __future__ import annotations

import logging

import numpy as np
import pytest

from dream.errors import InputError
from dream.robot.visuals import load_mesh_parts

COLLADA = """<?xml version="1.0" encoding="utf-8"?>
<COLLADA xmlns="http://www.collada.org/2005/11/COLLADASchema" version="1.4.1">
  <asset><unit name="meter" meter="1"/><up_axis>Z_UP</up_axis></asset>
  <library_geometries>
    <geometry id="tri-mesh" name="tri">
      <mesh>
        <source id="tri-positions">
          <float_array id="tri-positions-array" count="12">
            0 0 0 0.1 0 0 0 0.2 0 0 0 0.3</float_array>
          <technique_common>
            <accessor source="#tri-positions-array" count="4" stride="3">
              <param name="X" type="float"/><param name="Y" type="float"/>
              <param name="Z" type="float"/>
            </accessor>
          </technique_common>
        </source>
        <vertices id="tri-vertices"><input semantic="POSITION" source="#tri-positions"/></vertices>
        <triangles material="paint-material" count="2">
          <input semantic="VERTEX" source="#tri-vertices" offset="0"/>
          <p>0 1 2 0 2 3</p>
        </triangles>
      </mesh>
    </geometry>
  </library_geometries>
  <library_visual_scenes>
    <visual_scene id="Scene" name="Scene">
      <node id="part" name="part" type="NODE">
        <matrix sid="transform">1 0 0 0.5 0 1 0 0 0 0 1 0 0 0 0 1</matrix>
        <instance_geometry url="#tri-mesh" name="part">
          <bind_material>
            <technique_common>
              <instance_material symbol="paint-material" target="#MATERIAL"/>
            </technique_common>
          </bind_material>
        </instance_geometry>
      </node>
    </visual_scene>
  </library_visual_scenes>
  <scene><instance_visual_scene url="#Scene"/></scene>
</COLLADA>
"""


def test_a_node_binding_a_missing_material_keeps_its_triangles(tmp_path, caplog):
    path = tmp_path / "broken_material.dae"
    path.write_text(COLLADA.replace("MATERIAL", "missing-material"))
    with caplog.at_level(logging.WARNING):
        parts = load_mesh_parts(path)
    assert len(parts) == 1 and parts[0].rgba is None     # the URDF's colour
    assert len(parts[0].faces) == 2
    np.testing.assert_allclose(np.sort(parts[0].vertices[:, 0]), [0.5, 0.5, 0.5, 0.6],
                               atol=1e-6)                 # the node's transform applied
    assert "materials refer to parts the file lacks" in caplog.text


def test_a_file_without_triangles_is_still_one_error(tmp_path):
    path = tmp_path / "empty.dae"
    path.write_text(COLLADA.replace('count="2">', 'count="0">').replace("<p>0 1 2 0 2 3</p>",
                                                                        "<p></p>"))
    with pytest.raises(InputError, match="holds no triangles"):
        load_mesh_parts(path)
