// 3D views: each model is embedded gzipped (data-glb-gz, base64) and unpacked into a blob: URL for
// its <model-viewer> the first time its <details> opens, so the page opens without decoding any.
async function unpack(view) {
  if (view.src) return;
  const bytes = Uint8Array.from(atob(view.dataset.glbGz), (c) => c.charCodeAt(0));
  const stream = new Blob([bytes]).stream().pipeThrough(new DecompressionStream("gzip"));
  const glb = await new Response(stream).blob();
  view.src = URL.createObjectURL(new Blob([glb], {type: "model/gltf-binary"}));
}
document.querySelectorAll("model-viewer[data-glb-gz]").forEach((view) => {
  const open = () => unpack(view).catch((e) => {
    console.error(`3D view ${view.alt}: cannot unpack its model: ${e}`);
    view.dispatchEvent(new CustomEvent("error", {detail: {type: "unpack", message: String(e)}}));
  });
  const box = view.closest("details");
  if (box) box.addEventListener("toggle", () => box.open && open());
  else open();
});
