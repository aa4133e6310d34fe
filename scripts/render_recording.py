#!/usr/bin/python3
# SPDX-License-Identifier: Apache-2.0
"""Renders one frame of a recording (.pvd or .vtu) offscreen with VTK: the body's surface
coloured by the magnitude of its displacement, the rest shape as a grey wireframe. Run it through
scripts/render-recording.sh (which supplies an X server with xvfb-run when there is no display).

usage: render_recording.py RECORDING.pvd|FRAME.vtu OUT.png [--frame K] [--size WxH] [--title T]
"""
import argparse
import os
import xml.etree.ElementTree as ET

import vtk


def frame_file(path, k):
    if not path.endswith(".pvd"):
        return path
    files = [ds.get("file") for ds in ET.parse(path).getroot().iter("DataSet")]
    return os.path.join(os.path.dirname(path), files[k])


def main():
    p = argparse.ArgumentParser()
    p.add_argument("recording")
    p.add_argument("out")
    p.add_argument("--frame", type=int, default=-1, help="index in the .pvd (default: the last)")
    p.add_argument("--size", default="1200x800")
    p.add_argument("--title", default="")
    a = p.parse_args()
    w, h = (int(v) for v in a.size.split("x"))

    reader = vtk.vtkXMLUnstructuredGridReader()
    reader.SetFileName(frame_file(a.recording, a.frame))
    reader.Update()
    grid = reader.GetOutput()

    # |displacement| per point, for the colours.
    disp = grid.GetPointData().GetArray("displacement")
    mag = vtk.vtkDoubleArray()
    mag.SetName("|displacement|")
    mag.SetNumberOfTuples(disp.GetNumberOfTuples())
    for i in range(disp.GetNumberOfTuples()):
        x, y, z = disp.GetTuple3(i)
        mag.SetValue(i, (x * x + y * y + z * z) ** 0.5)
    grid.GetPointData().AddArray(mag)
    grid.GetPointData().SetActiveScalars("|displacement|")

    surface = vtk.vtkDataSetSurfaceFilter()
    surface.SetInputData(grid)
    normals = vtk.vtkPolyDataNormals()
    normals.SetInputConnection(surface.GetOutputPort())
    normals.SetFeatureAngle(60)
    lut = vtk.vtkLookupTable()
    lut.SetHueRange(0.66, 0.0)
    lut.Build()
    mapper = vtk.vtkPolyDataMapper()
    mapper.SetInputConnection(normals.GetOutputPort())
    mapper.SetScalarModeToUsePointFieldData()
    mapper.SelectColorArray("|displacement|")
    mapper.SetScalarRange(mag.GetRange())
    mapper.SetLookupTable(lut)
    body = vtk.vtkActor()
    body.SetMapper(mapper)

    # The rest shape: points - displacement.
    rest = vtk.vtkUnstructuredGrid()
    rest.DeepCopy(grid)
    pts = rest.GetPoints()
    for i in range(pts.GetNumberOfPoints()):
        x, y, z = pts.GetPoint(i)
        dx, dy, dz = disp.GetTuple3(i)
        pts.SetPoint(i, x - dx, y - dy, z - dz)
    rest_surface = vtk.vtkDataSetSurfaceFilter()
    rest_surface.SetInputData(rest)
    rest_mapper = vtk.vtkPolyDataMapper()
    rest_mapper.SetInputConnection(rest_surface.GetOutputPort())
    rest_mapper.ScalarVisibilityOff()
    ghost = vtk.vtkActor()
    ghost.SetMapper(rest_mapper)
    ghost.GetProperty().SetRepresentationToWireframe()
    ghost.GetProperty().SetColor(0.6, 0.6, 0.6)
    ghost.GetProperty().SetOpacity(0.25)

    bar = vtk.vtkScalarBarActor()
    bar.SetLookupTable(lut)
    bar.SetTitle("|u| (m)")
    bar.SetNumberOfLabels(4)
    bar.SetWidth(0.08)
    bar.SetHeight(0.6)

    ren = vtk.vtkRenderer()
    ren.SetBackground(1, 1, 1)
    ren.AddActor(ghost)
    ren.AddActor(body)
    ren.AddActor2D(bar)
    bar.GetTitleTextProperty().SetColor(0, 0, 0)
    bar.GetLabelTextProperty().SetColor(0, 0, 0)
    if a.title:
        text = vtk.vtkTextActor()
        text.SetInput(a.title)
        text.GetTextProperty().SetColor(0, 0, 0)
        text.GetTextProperty().SetFontSize(20)
        text.SetPosition(12, h - 36)
        ren.AddActor2D(text)
    cam = ren.GetActiveCamera()
    cam.SetPosition(0.6, 0.35, 1.0)
    cam.SetFocalPoint(0, 0, 0)
    cam.SetViewUp(0, 1, 0)
    ren.ResetCamera()
    cam.Zoom(1.3)

    win = vtk.vtkRenderWindow()
    win.SetOffScreenRendering(1)
    win.SetSize(w, h)
    win.AddRenderer(ren)
    win.Render()
    grab = vtk.vtkWindowToImageFilter()
    grab.SetInput(win)
    grab.Update()
    png = vtk.vtkPNGWriter()
    png.SetFileName(a.out)
    png.SetInputConnection(grab.GetOutputPort())
    png.Write()
    print(f"wrote {a.out} ({grid.GetNumberOfPoints()} points, {grid.GetNumberOfCells()} tets, "
          f"max |u| {mag.GetRange()[1]:.4g} m)")


if __name__ == "__main__":
    main()
