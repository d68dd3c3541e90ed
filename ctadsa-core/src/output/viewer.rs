//! The report's interactive 3-D view: the completed surface (prior part and new vessels in two
//! colours) drawn by three.js (vendored, `viewer/README.md`), rotatable with the mouse, all
//! inside the one HTML file (the library and the meshes as data, no network).

use base64::Engine as _;

use crate::data::mesh::TriMesh;

const THREE: &str = include_str!("viewer/three.module.min.js");
const ORBIT_CONTROLS: &str = include_str!("viewer/OrbitControls.js");

/// More triangles than this and the view is left out (the page would grow past ~30 MB).
pub const MAX_VIEWER_TRIANGLES: usize = 1_500_000;

/// One coloured part of the view.
pub struct ViewerPart<'a> {
    pub name: &'a str,
    pub mesh: &'a TriMesh,
    pub rgb: [u8; 3],
}

fn b64(bytes: &[u8]) -> String {
    base64::engine::general_purpose::STANDARD.encode(bytes)
}

/// The parts as JSON: name, colour, positions (f32 mm, little endian) and indices (u32), both
/// base64.
fn parts_json(parts: &[ViewerPart]) -> String {
    let items: Vec<String> = parts
        .iter()
        .filter(|p| !p.mesh.is_empty())
        .map(|p| {
            let positions: Vec<u8> = p
                .mesh
                .vertices
                .iter()
                .flat_map(|v| [v.x as f32, v.y as f32, v.z as f32])
                .flat_map(f32::to_le_bytes)
                .collect();
            let indices: Vec<u8> = p.mesh.faces.iter().flatten().flat_map(|i| i.to_le_bytes()).collect();
            format!(
                "{{\"name\":{:?},\"rgb\":[{},{},{}],\"positions\":\"{}\",\"indices\":\"{}\"}}",
                p.name,
                p.rgb[0],
                p.rgb[1],
                p.rgb[2],
                b64(&positions),
                b64(&indices)
            )
        })
        .collect();
    format!("[{}]", items.join(","))
}

/// The HTML of the view (a canvas, the data and the scripts), or a note when the meshes are too
/// large. After drawing, the page records how many canvas pixels are not background in
/// `document.body.dataset.viewerPixels` (or the failure in `viewerError`).
pub fn viewer_html(parts: &[ViewerPart]) -> String {
    let triangles: usize = parts.iter().map(|p| p.mesh.faces.len()).sum();
    if triangles > MAX_VIEWER_TRIANGLES {
        return format!("<p>3-D view left out: {triangles} triangles (at most {MAX_VIEWER_TRIANGLES}).</p>");
    }
    format!(
        "<div id=\"viewer\" style=\"width:100%;height:540px;border:1px solid #ccc\"></div>\
         <p>Drag to rotate, scroll to zoom, right-drag to pan.</p>\
         <script type=\"application/json\" id=\"viewer-data\">{data}</script>\
         <script type=\"importmap\">{{\"imports\":{{\"three\":\"data:text/javascript;base64,{three}\"}}}}</script>\
         <script type=\"module\">{script}</script>",
        data = parts_json(parts),
        three = b64(THREE.as_bytes()),
        script = SCRIPT
            .replace("ORBIT_CONTROLS_URL", &format!("data:text/javascript;base64,{}", b64(ORBIT_CONTROLS.as_bytes()))),
    )
}

const SCRIPT: &str = r#"
import * as THREE from 'three';
import { OrbitControls } from 'ORBIT_CONTROLS_URL';
try {
  const el = document.getElementById('viewer');
  const parts = JSON.parse(document.getElementById('viewer-data').textContent);
  const w = el.clientWidth, h = el.clientHeight;
  const renderer = new THREE.WebGLRenderer({ antialias: true, preserveDrawingBuffer: true });
  renderer.setPixelRatio(1);
  renderer.setSize(w, h);
  renderer.setClearColor(0xffffff);
  el.appendChild(renderer.domElement);
  const scene = new THREE.Scene();
  const camera = new THREE.PerspectiveCamera(35, w / h, 0.1, 100000);
  const bytes = (s) => Uint8Array.from(atob(s), (c) => c.charCodeAt(0)).buffer;
  const box = new THREE.Box3();
  for (const p of parts) {
    const g = new THREE.BufferGeometry();
    g.setAttribute('position', new THREE.BufferAttribute(new Float32Array(bytes(p.positions)), 3));
    g.setIndex(new THREE.BufferAttribute(new Uint32Array(bytes(p.indices)), 1));
    g.computeVertexNormals();
    g.computeBoundingBox();
    box.union(g.boundingBox);
    const color = new THREE.Color(p.rgb[0] / 255, p.rgb[1] / 255, p.rgb[2] / 255);
    scene.add(new THREE.Mesh(g, new THREE.MeshLambertMaterial({ color, side: THREE.DoubleSide })));
  }
  scene.add(new THREE.AmbientLight(0xffffff, 0.6));
  const light = new THREE.DirectionalLight(0xffffff, 1.8);
  camera.add(light);
  scene.add(camera);
  const centre = box.getCenter(new THREE.Vector3());
  const radius = Math.max(box.getSize(new THREE.Vector3()).length() / 2, 1);
  camera.up.set(0, 0, 1); // world +z is superior
  camera.position.set(centre.x, centre.y - 3 * radius, centre.z);
  camera.lookAt(centre);
  const controls = new OrbitControls(camera, renderer.domElement);
  controls.target.copy(centre);
  controls.update();
  const draw = () => renderer.render(scene, camera);
  controls.addEventListener('change', draw);
  draw();
  const gl = renderer.getContext();
  const px = new Uint8Array(w * h * 4);
  gl.readPixels(0, 0, w, h, gl.RGBA, gl.UNSIGNED_BYTE, px);
  let drawn = 0;
  for (let i = 0; i < px.length; i += 4) if (px[i] < 245 || px[i + 1] < 245 || px[i + 2] < 245) drawn++;
  document.body.dataset.viewerPixels = drawn;
} catch (e) {
  document.body.dataset.viewerError = String(e);
}
"#;
