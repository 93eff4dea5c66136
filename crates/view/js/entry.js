// The viewer's third-party code as one global, `KinetreeVendor`, so that a single
// self-contained HTML file can carry it in a classic <script> (no module loading). Only the
// three.js classes the viewer uses are imported, so that the bundle leaves the rest out.
import {
  BufferAttribute,
  BufferGeometry,
  Color,
  DynamicDrawUsage,
  LineBasicMaterial,
  LineSegments,
  PerspectiveCamera,
  Points,
  PointsMaterial,
  Scene,
  Sphere,
  Vector3,
  WebGLRenderer,
} from "three";
import { OrbitControls } from "three/examples/jsm/controls/OrbitControls.js";
import uPlot from "uplot";

globalThis.KinetreeVendor = {
  THREE: {
    BufferAttribute,
    BufferGeometry,
    Color,
    DynamicDrawUsage,
    LineBasicMaterial,
    LineSegments,
    PerspectiveCamera,
    Points,
    PointsMaterial,
    Scene,
    Sphere,
    Vector3,
    WebGLRenderer,
  },
  OrbitControls,
  uPlot,
};
