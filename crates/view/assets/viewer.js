// The kinetree viewer: draws the data that `kinetree view` put in the page with three.js
// (scene, orbit controls) and uPlot (the joint positions over time). Exposes
// `window.kinetreeViewer` (setFrame, play, pause, frame, nFrames) for scripts and tests.
"use strict";
(function () {
  const { THREE, OrbitControls, uPlot } = globalThis.KinetreeVendor;
  const data = JSON.parse(document.getElementById("kinetree-data").textContent);

  // Arrays arrive as base64 of little-endian float32, NaN where unknown.
  function floats(text) {
    const raw = atob(text);
    const bytes = new Uint8Array(raw.length);
    for (let i = 0; i < raw.length; i++) bytes[i] = raw.charCodeAt(i);
    return new Float32Array(bytes.buffer);
  }

  const nFrames = data.frames.length;
  const nPoints = data.n_points;
  const tracks = floats(data.positions);
  const bodies = data.bodies.map((b) => Object.assign({}, b, { origin: floats(b.origin) }));
  const joints = data.joints.map((j) =>
    Object.assign({}, j, {
      pivot: floats(j.pivot),
      axis: floats(j.axis),
      position: floats(j.position),
    })
  );

  // Colours: one per body, the static background in slate, points on no body in light grey.
  const PALETTE = ["#1f77b4", "#ff7f0e", "#2ca02c", "#d62728", "#9467bd", "#8c564b",
    "#e377c2", "#17becf", "#bcbd22", "#393b79", "#637939", "#ad494a"];
  function bodyColour(id) {
    if (id < 0 || id >= bodies.length) return "#c8c8c8";
    return bodies[id].is_static ? "#5f6f80" : PALETTE[id % PALETTE.length];
  }

  // The scene's extent, from every visible sample.
  const lo = [Infinity, Infinity, Infinity];
  const hi = [-Infinity, -Infinity, -Infinity];
  for (let k = 0; k < tracks.length; k += 3) {
    if (Number.isNaN(tracks[k])) continue;
    for (let c = 0; c < 3; c++) {
      lo[c] = Math.min(lo[c], tracks[k + c]);
      hi[c] = Math.max(hi[c], tracks[k + c]);
    }
  }
  const centre = new THREE.Vector3((lo[0] + hi[0]) / 2, (lo[1] + hi[1]) / 2, (lo[2] + hi[2]) / 2);
  const size = Math.max(hi[0] - lo[0], hi[1] - lo[1], hi[2] - lo[2], 1e-3) || 1;

  const host = document.getElementById("view3d");
  const renderer = new THREE.WebGLRenderer({ antialias: true, preserveDrawingBuffer: true });
  renderer.setPixelRatio(window.devicePixelRatio || 1);
  host.appendChild(renderer.domElement);
  const scene = new THREE.Scene();
  scene.background = new THREE.Color(0xffffff);
  const camera = new THREE.PerspectiveCamera(45, 1, size / 1000, size * 100);
  // Tracks are in a camera frame (x right, y down, z ahead): start near that camera's view.
  camera.up.set(0, -1, 0);
  camera.position.set(centre.x + 0.6 * size, centre.y - 0.4 * size, centre.z - 1.8 * size);
  const controls = new OrbitControls(camera, renderer.domElement);
  controls.target.copy(centre);
  controls.update();

  // Geometry whose vertices change every frame: filled compactly, hidden ones left out, so
  // that no NaN reaches three.js.
  function dynamic(capacity, material, Kind) {
    const geometry = new THREE.BufferGeometry();
    const position = new THREE.BufferAttribute(new Float32Array(Math.max(capacity, 1) * 3), 3);
    const colour = new THREE.BufferAttribute(new Float32Array(Math.max(capacity, 1) * 3), 3);
    position.setUsage(THREE.DynamicDrawUsage);
    colour.setUsage(THREE.DynamicDrawUsage);
    geometry.setAttribute("position", position);
    geometry.setAttribute("color", colour);
    geometry.boundingSphere = new THREE.Sphere(centre.clone(), 100 * size);
    const object = new Kind(geometry, material);
    object.frustumCulled = false;
    scene.add(object);
    let count = 0;
    return {
      reset() { count = 0; },
      push(x, y, z, rgb) {
        position.setXYZ(count, x, y, z);
        colour.setXYZ(count, rgb.r, rgb.g, rgb.b);
        count++;
      },
      finish() {
        geometry.setDrawRange(0, count);
        position.needsUpdate = true;
        colour.needsUpdate = true;
      },
    };
  }

  const pointLayer = dynamic(nPoints,
    new THREE.PointsMaterial({ size: 7, sizeAttenuation: false, vertexColors: true }), THREE.Points);
  const linkLayer = dynamic(4 * joints.length,
    new THREE.LineBasicMaterial({ vertexColors: true }), THREE.LineSegments);
  const axisLayer = dynamic(2 * joints.length,
    new THREE.LineBasicMaterial({ vertexColors: true }), THREE.LineSegments);
  const pivotLayer = dynamic(joints.length,
    new THREE.PointsMaterial({ size: 11, sizeAttenuation: false, vertexColors: true }), THREE.Points);

  const pointRgb = data.point_body.map((b) => new THREE.Color(bodyColour(b)));
  const linkRgb = new THREE.Color("#222222");
  const jointRgb = joints.map((j) => new THREE.Color(bodyColour(j.child)));

  function at(array, f) {
    const x = array[3 * f];
    return Number.isNaN(x) ? null : [x, array[3 * f + 1], array[3 * f + 2]];
  }

  let frame = 0;
  function drawFrame() {
    pointLayer.reset();
    const base = frame * nPoints * 3;
    for (let i = 0; i < nPoints; i++) {
      const k = base + 3 * i;
      if (!Number.isNaN(tracks[k])) pointLayer.push(tracks[k], tracks[k + 1], tracks[k + 2], pointRgb[i]);
    }
    pointLayer.finish();
    linkLayer.reset();
    axisLayer.reset();
    pivotLayer.reset();
    const reach = 0.15 * size;
    joints.forEach((j, k) => {
      const from = at(bodies[j.parent].origin, frame);
      const to = at(bodies[j.child].origin, frame);
      const pivot = at(j.pivot, frame);
      const axis = at(j.axis, frame);
      // The link: parent's origin to the pivot to the child's origin.
      const path = [from, pivot, to].filter((p) => p !== null);
      for (let s = 0; s + 1 < path.length; s++) {
        linkLayer.push(...path[s], linkRgb);
        linkLayer.push(...path[s + 1], linkRgb);
      }
      if (pivot) pivotLayer.push(...pivot, jointRgb[k]);
      // The axis through the pivot (a hinge) or the child's origin (a slide).
      const through = pivot || to;
      if (axis && through) {
        axisLayer.push(through[0] - reach * axis[0], through[1] - reach * axis[1], through[2] - reach * axis[2], jointRgb[k]);
        axisLayer.push(through[0] + reach * axis[0], through[1] + reach * axis[1], through[2] + reach * axis[2], jointRgb[k]);
      }
    });
    linkLayer.finish();
    axisLayer.finish();
    pivotLayer.finish();
  }

  // Drawing on demand: a change asks for one render at the next animation frame.
  let renderQueued = false;
  function requestRender() {
    if (renderQueued) return;
    renderQueued = true;
    requestAnimationFrame(() => {
      renderQueued = false;
      renderer.render(scene, camera);
      if (plot) plot.redraw(false, false);
    });
  }
  controls.addEventListener("change", requestRender);

  function resize() {
    const w = Math.max(host.clientWidth, 1);
    const h = Math.max(host.clientHeight, 1);
    renderer.setSize(w, h);
    camera.aspect = w / h;
    camera.updateProjectionMatrix();
    requestRender();
  }
  window.addEventListener("resize", resize);

  // Controls.
  const slider = document.getElementById("frame");
  const label = document.getElementById("frame-label");
  const playButton = document.getElementById("play");
  slider.max = String(Math.max(nFrames - 1, 0));
  function setFrame(f) {
    frame = Math.min(Math.max(Math.round(f), 0), nFrames - 1);
    slider.value = String(frame);
    label.textContent = "frame " + data.frames[frame] + " (" + (frame + 1) + "/" + nFrames + ")";
    drawFrame();
    requestRender();
  }
  slider.addEventListener("input", () => setFrame(Number(slider.value)));

  let playing = false;
  let clock = 0;
  let last = 0;
  function tick(now) {
    if (!playing) return;
    clock += ((now - last) / 1000) * data.fps;
    last = now;
    if (clock >= 1) {
      const step = Math.floor(clock);
      clock -= step;
      setFrame((frame + step) % nFrames);
    }
    requestAnimationFrame(tick);
  }
  function play() {
    if (playing || nFrames < 2) return;
    playing = true;
    playButton.textContent = "Pause";
    last = performance.now();
    requestAnimationFrame(tick);
  }
  function pause() {
    playing = false;
    playButton.textContent = "Play";
  }
  playButton.addEventListener("click", () => (playing ? pause() : play()));
  window.addEventListener("keydown", (e) => {
    if (e.code === "Space" && e.target === document.body) {
      e.preventDefault();
      playing ? pause() : play();
    }
  });

  // The title, the legend and the summary.
  document.getElementById("title").textContent = data.title;
  const legend = document.getElementById("bodies");
  bodies.forEach((b) => {
    const item = document.createElement("span");
    const swatch = document.createElement("span");
    swatch.className = "swatch";
    swatch.style.background = bodyColour(b.id);
    item.appendChild(swatch);
    item.appendChild(document.createTextNode(
      "body " + b.id + (b.is_static ? " (static)" : "") + ", " + b.n_points + " points"));
    legend.appendChild(item);
  });
  const unassigned = data.point_body.filter((b) => b < 0).length;
  document.getElementById("summary").textContent =
    bodies.length + " bodies, " + joints.length + " joints, " + nPoints + " keypoints" +
    (unassigned ? " (" + unassigned + " on no body)" : "") + "; noise " +
    (1000 * data.noise_sigma_m).toPrecision(3) + " mm" +
    (data.frames.length > 1 && data.frames[1] - data.frames[0] > 1
      ? "; every " + (data.frames[1] - data.frames[0]) + "th frame shown" : "");
  document.getElementById("joints").textContent = joints
    .map((j) => j.type + " " + j.parent + "\u2192" + j.child)
    .join(", ");

  // Joint positions over time, one series per joint with a coordinate; a vertical line
  // marks the frame shown, and a click on the plot goes to that frame.
  let plot = null;
  const plotted = joints.filter((j) => j.unit !== null);
  if (plotted.length > 0 && nFrames > 1) {
    const xs = Array.from(data.frames);
    const columns = [xs].concat(plotted.map((j) =>
      Array.from(j.position, (v) => (Number.isNaN(v) ? null : v))));
    const units = [...new Set(plotted.map((j) => j.unit))];
    const scales = { x: { time: false } };
    units.forEach((u) => (scales[u] = {}));
    const axes = [{ label: "frame" }].concat(units.map((u, k) => ({
      scale: u, label: u === "rad" ? "angle (rad)" : "slide (m)", side: k === 0 ? 3 : 1,
      grid: { show: k === 0 },
    })));
    const series = [{ label: "frame" }].concat(plotted.map((j) => ({
      label: j.name, scale: j.unit, stroke: bodyColour(j.child), width: 1.5, spanGaps: false,
    })));
    plot = new uPlot({
      width: 420,
      height: 240,
      scales,
      axes,
      series,
      legend: { live: true },
      hooks: {
        draw: [(u) => {
          const x = u.valToPos(data.frames[frame], "x", true);
          const ctx = u.ctx;
          ctx.save();
          ctx.strokeStyle = "#444";
          ctx.lineWidth = 1;
          ctx.beginPath();
          ctx.moveTo(x, u.bbox.top);
          ctx.lineTo(x, u.bbox.top + u.bbox.height);
          ctx.stroke();
          ctx.restore();
        }],
      },
    }, columns, document.getElementById("plot"));
    plot.over.addEventListener("click", () => {
      if (plot.cursor.idx !== null && plot.cursor.idx !== undefined) setFrame(plot.cursor.idx);
    });
  } else {
    document.getElementById("plot").textContent = "No joint with a coordinate to plot.";
  }

  resize();
  setFrame(0);
  window.kinetreeViewer = {
    nFrames,
    setFrame,
    play,
    pause,
    get frame() { return frame; },
    get playing() { return playing; },
    ready: true,
  };
})();
