// SPDX-License-Identifier: Apache-2.0
// Malformed input: each case in the table fails with its own specific message (file, line or
// element, value); repairs of inverted and zero-volume tets. Truncations and byte garbage at
// every position: test_mesh_fuzz.cpp.
#include "pliant/builtin_meshes.hpp"
#include "pliant/mesh_io.hpp"
#include "test_helpers.hpp"

#include <gtest/gtest.h>

using namespace pliant;
using pliant::test::data_file;
using pliant::test::ScratchDir;

namespace {

MeshLoadOptions quiet() {
  MeshLoadOptions o;
  o.validation.log = false;
  return o;
}

const char* kCubeNode = "8 3 0 0\n0 0 0 0\n1 1 0 0\n2 0 1 0\n3 1 1 0\n4 0 0 1\n5 1 0 1\n6 0 1 1\n7 1 1 1\n";
const char* kCubeEle = "5 4 0\n0 0 1 2 4\n1 1 3 2 7\n2 1 4 5 7\n3 2 4 7 6\n4 1 2 4 7\n";

struct BadCase {
  const char* name;
  const char* file;     // written to the scratch dir; a .node gets kCubeEle beside it unless `other` is set
  std::string content;
  const char* other;    // content of the companion .ele (for .node cases); nullptr: kCubeEle
  const char* expect;   // substring of the MeshError message
};

std::string replace(std::string s, const std::string& from, const std::string& to) {
  const size_t at = s.find(from);
  if (at != std::string::npos) s.replace(at, from.size(), to);
  return s;
}

std::vector<BadCase> bad_cases() {
  const std::string node = kCubeNode;
  const std::string ele = kCubeEle;
  return {
      {"TruncatedNode", "t.node", node.substr(0, 40), nullptr, "t.node:1: number of points 8 cannot fit in the 33 bytes left"},
      {"TruncatedMidLine", "t.node", "3 3 0 0\n0 0.000000 0.000000 0.000000\n1 1.000000 0.000000 0.000000\n2 0.0000", nullptr,
       "t.node:4: unexpected end of file while reading a coordinate"},
      {"TruncatedEle", "t.node", node, "5 4 0\n0 0 1 2 4\n1 1 3", "t.ele:1: number of tetrahedra 5 cannot fit"},
      {"NegativeCount", "t.node", replace(node, "8 3", "-8 3"), nullptr, "negative number of points: -8"},
      {"HugeCount", "t.node", replace(node, "8 3", "900000000000 3"), nullptr, "number of points 900000000000 cannot fit"},
      {"CountTooSmall", "t.node", replace(node, "8 3", "7 3"), nullptr, "t.node:9: more data after the 7 points"},
      {"BadDimension", "t.node", replace(node, "8 3", "8 2"), nullptr, "dimension must be 3, got 2"},
      {"NonConsecutive", "t.node", replace(node, "\n5 1 0 1", "\n9 1 0 1"), nullptr, "t.node:7: point indices must be consecutive: expected 5, got 9"},
      {"BadFirstIndex", "t.node", replace(node, "\n0 0 0 0", "\n3 0 0 0"), nullptr, "first point index must be 0 or 1, got 3"},
      {"NotANumber", "t.node", replace(node, "2 0 1 0", "2 0 1.2.3 0"), nullptr, "t.node:4: expected a number for a coordinate, got '1.2.3'"},
      {"NaN", "t.node", replace(node, "2 0 1 0", "2 0 nan 0"), nullptr, "t.node:4: point 2: non-finite coordinate"},
      {"Inf", "t.node", replace(node, "2 0 1 0", "2 0 inf 0"), nullptr, "non-finite coordinate inf"},
      {"IndexOutOfRange", "t.node", node, "5 4 0\n0 0 1 2 4\n1 1 3 2 8\n2 1 4 5 7\n3 2 4 7 6\n4 1 2 4 7\n",
       "t.ele:3: tet 1: vertex index 8 out of range [0, 7]"},
      {"NegativeIndex", "t.node", node, "5 4 0\n0 0 1 2 4\n1 1 3 2 -1\n2 1 4 5 7\n3 2 4 7 6\n4 1 2 4 7\n",
       "vertex index -1 out of range"},
      {"RepeatedIndex", "t.node", node, "5 4 0\n0 0 1 2 4\n1 1 3 3 7\n2 1 4 5 7\n3 2 4 7 6\n4 1 2 4 7\n",
       "t.ele:3: tet 1: repeats vertex 3 (zero volume"},
      {"Degenerate", "t.node", node, "5 4 0\n0 0 1 2 3\n1 1 3 2 7\n2 1 4 5 7\n3 2 4 7 6\n4 1 2 4 7\n",
       "t.ele:2: tet 0: degenerate tet, volume 0"},
      {"QuadraticNodesPerTet", "t.node", node, "5 6 0\n", "nodes per tetrahedron must be 4 or 10, got 6"},
      {"EmptyNode", "t.node", "", nullptr, "unexpected end of file while reading the number of points"},
      {"GmshTruncated", "t.msh", "$MeshFormat\n2.2 0 8\n$EndMeshFormat\n$Nodes\n2\n1 0.0 0.0 0.0\n2 1.0 0.0", nullptr,
       "t.msh:7: unexpected end of file while reading a coordinate"},
      {"GmshBadNodeCount", "t.msh", "$MeshFormat\n2.2 0 8\n$EndMeshFormat\n$Nodes\n8\n1 0 0 0\n2 1 0 0\n", nullptr,
       "t.msh:5: number of nodes 8 cannot fit"},
      {"GmshUndefinedNode", "t.msh",
       "$MeshFormat\n2.2 0 8\n$EndMeshFormat\n$Nodes\n4\n1 0 0 0\n2 1 0 0\n3 0 1 0\n4 0 0 1\n$EndNodes\n"
       "$Elements\n1\n7 4 2 0 0 1 2 3 99\n$EndElements\n",
       nullptr, "t.msh:13: element 7: node 99 is not defined"},
      {"GmshBadCount", "t.msh",
       "$MeshFormat\n2.2 0 8\n$EndMeshFormat\n$Nodes\n3\n1 0 0 0\n2 1 0 0\n3 0 1 0\n4 0 0 1\n$EndNodes\n", nullptr,
       "t.msh:9: expected $EndNodes, got '4' (bad count?)"},
      {"GmshVersion", "t.msh", "$MeshFormat\n3.0 0 8\n$EndMeshFormat\n", nullptr, "unsupported Gmsh format version '3.0'"},
      {"GmshNoTets", "t.msh",
       "$MeshFormat\n2.2 0 8\n$EndMeshFormat\n$Nodes\n3\n1 0 0 0\n2 1 0 0\n3 0 1 0\n$EndNodes\n"
       "$Elements\n1\n1 2 0 1 2 3\n$EndElements\n",
       nullptr, "no tetrahedra in the file"},
      {"GmshUnclosedSection", "t.msh", "$MeshFormat\n2.2 0 8\n$EndMeshFormat\n$Comments\nblah\n", nullptr,
       "t.msh:4: section $Comments has no $EndComments"},
      {"VtkNotVtk", "t.vtk", "hello\n", nullptr, "not a VTK legacy file"},
      {"VtkPolydata", "t.vtk", "# vtk DataFile Version 2.0\nx\nASCII\nDATASET POLYDATA\n", nullptr,
       "only UNSTRUCTURED_GRID datasets hold tets, got 'POLYDATA'"},
      {"VtkTypeCountMismatch", "t.vtk",
       "# vtk DataFile Version 2.0\nx\nASCII\nDATASET UNSTRUCTURED_GRID\nPOINTS 4 float\n0 0 0\n1 0 0\n0 1 0\n0 0 1\n"
       "CELLS 1 5\n4 0 1 2 3\nCELL_TYPES 2\n10\n10\n",
       nullptr, "CELL_TYPES lists 2 cells, CELLS lists 1"},
      {"VtkCellOverrun", "t.vtk",
       "# vtk DataFile Version 2.0\nx\nASCII\nDATASET UNSTRUCTURED_GRID\nPOINTS 4 float\n0 0 0\n1 0 0\n0 1 0\n0 0 1\n"
       "CELLS 1 5\n9 0 1 2 3\nCELL_TYPES 1\n10\n",
       nullptr, "t.vtk:11: cell 0: point count 9 overruns the cell list size 5"},
      {"VtkIndex", "t.vtk",
       "# vtk DataFile Version 2.0\nx\nASCII\nDATASET UNSTRUCTURED_GRID\nPOINTS 4 float\n0 0 0\n1 0 0\n0 1 0\n0 0 1\n"
       "CELLS 1 5\n4 0 1 2 4\nCELL_TYPES 1\n10\n",
       nullptr, "cell 0: point index 4 out of range [0, 3]"},
      {"VtuCompressed", "t.vtu",
       "<VTKFile type=\"UnstructuredGrid\" compressor=\"vtkLZMADataCompressor\"><UnstructuredGrid></UnstructuredGrid></VTKFile>",
       nullptr, "compressor vtkLZMADataCompressor is not supported (vtkZLibDataCompressor is; or save uncompressed)"},
      {"VtuTruncated", "t.vtu",
       "<VTKFile type=\"UnstructuredGrid\">\n<UnstructuredGrid>\n<Piece NumberOfPoints=\"4\" NumberOfCells=\"1\">\n"
       "<Points>\n<DataArray type=\"Float64\" NumberOfComponents=\"3\" format=\"ascii\">\n0 0 0 1 0",
       nullptr, "t.vtu:4: <Points> is not closed (truncated file?)"},
      {"UnknownFormat", "t.xyz", "1 2 3\n", nullptr, "unknown tet-mesh format"},
      {"BinaryGarbageNode", "t.node", std::string("\x89PNG\r\n\x1a\n\0\0\0\rIHDR", 16), nullptr,
       "t.node:1: expected an integer for the number of points, got '\\x89PNG'"},
      {"BinaryGarbageVtk", "t.vtk", std::string("\x7f" "ELF\x02\x01\x01\0\0\0", 10), nullptr,
       "t.vtk:1: not a VTK legacy file"},
      {"BinaryGmshGarbageTags", "t.msh",
       std::string("$MeshFormat\n2.2 1 8\n\x01\0\0\0\n$EndMeshFormat\n$Nodes\n1\n", 49) +
           std::string("\x07\0\0\0", 4) + std::string(24, '\0') + "\n$EndNodes\n$Elements\n1\n" +
           std::string("\x04\0\0\0\x01\0\0\0\0\0\0\0\x05\0\0\0\xff\xff\xff\x7f\x07\0\0\0\x07\0\0\0\x07\0\0\0", 32) +
           "\n$EndElements\n",
       nullptr, "element 5: node 2147483647 is not defined"},
  };
}

void PrintTo(const BadCase& c, std::ostream* os) { *os << c.name; }

class Malformed : public ::testing::TestWithParam<BadCase> {};

}  // namespace

TEST_P(Malformed, FailsWithItsSpecificMessage) {
  const BadCase& c = GetParam();
  ScratchDir dir;
  const std::string path = dir.write(c.file, c.content);
  if (std::string(c.file).ends_with(".node")) dir.write("t.ele", c.other ? c.other : kCubeEle);
  try {
    load_mesh(path, quiet());
    FAIL() << "expected MeshError containing: " << c.expect;
  } catch (const MeshError& e) {
    EXPECT_NE(std::string(e.what()).find(c.expect), std::string::npos) << "message: " << e.what() << "\nexpected: " << c.expect;
  }
}

INSTANTIATE_TEST_SUITE_P(Table, Malformed, ::testing::ValuesIn(bad_cases()),
                         [](const ::testing::TestParamInfo<BadCase>& info) { return std::string(info.param.name); });

TEST(MalformedRepair, InvertedTetIsReorientedWithAWarningOrRejected) {
  ScratchDir dir;
  dir.write("t.node", kCubeNode);
  // Tet 1 (line 3) is inverted: two vertices swapped.
  dir.write("t.ele", "5 4 0\n0 0 1 2 4\n1 1 2 3 7\n2 1 4 5 7\n3 2 4 7 6\n4 1 2 4 7\n");
  const MeshLoadResult r = load_mesh_with_report(dir.file("t.node"), quiet());
  EXPECT_EQ(r.report.reoriented, 1);
  ASSERT_EQ(r.report.warnings.size(), 1u);
  EXPECT_NE(r.report.warnings[0].find("1 inverted tets re-oriented (first: t.ele:3: tet 1, volume -0.167"), std::string::npos)
      << r.report.warnings[0];
  for (size_t t = 0; t < r.mesh.tets.size(); ++t) EXPECT_GT(tet_volume(r.mesh, t), 0);
  EXPECT_NEAR(r.report.volume, 1.0, 1e-12);

  MeshLoadOptions strict = quiet();
  strict.validation.reorient_inverted = false;
  EXPECT_THROW(
      {
        try {
          load_mesh(dir.file("t.node"), strict);
        } catch (const MeshError& e) {
          EXPECT_NE(std::string(e.what()).find("t.ele:3: tet 1: inverted tet, volume -0.167"), std::string::npos) << e.what();
          throw;
        }
      },
      MeshError);
}

TEST(MalformedRepair, ZeroVolumeTetsAreDroppedOnRequest) {
  ScratchDir dir;
  // A sixth tet, flat (four vertices of the bottom face), after the five good ones.
  dir.write("t.node", kCubeNode);
  dir.write("t.ele", std::string("6 4 0\n0 0 1 2 4\n1 1 3 2 7\n2 1 4 5 7\n3 2 4 7 6\n4 1 2 4 7\n5 0 1 3 2\n"));
  EXPECT_THROW(load_mesh(dir.file("t.node"), quiet()), MeshError);
  MeshLoadOptions o = quiet();
  o.validation.drop_degenerate = true;
  const MeshLoadResult r = load_mesh_with_report(dir.file("t.node"), o);
  EXPECT_EQ(r.report.dropped_degenerate, 1);
  EXPECT_EQ(r.report.tets, 5);
  EXPECT_NEAR(r.report.volume, 1.0, 1e-12);
}
