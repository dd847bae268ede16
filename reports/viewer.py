"""An interactive, self-contained image comparison for the HTML report.

Each compared pair (own image, reference) becomes a small viewer in the
manner of tev and the Cycles render-test report:

* modes ``own``, ``reference``, ``error`` (the report's relative error map,
  ``|own − ref| / (|ref| + eps)`` averaged over channels, colormap inferno on
  [0, 1]) and ``split`` (own left of a divider that follows the cursor,
  reference right of it); keys 1-4 choose them, ``f`` flips between own and
  reference;
* an exposure control in stops (sRGB display of ``2^stops × base`` where
  ``base`` is the report's common exposure);
* the linear RGB values of own and reference and the relative error under
  the cursor;
* zoom ×1 to ×16 with nearest-neighbour pixels (buttons or ``+``/``-``).

Everything is inline (the page stays one file, no network).  The pixel data
travel as base64 little-endian float16 arrays of the images *as displayed*:
images whose longer side exceeds the report's display limit are box-filtered
first, so the values under the cursor are those of the displayed pixels,
to half precision (3 significant digits; values above 65504 show as
infinity).  Without JavaScript the static triplet the viewer wraps stays on
the page: :func:`wrap` only adds a data block and a class.
"""

from __future__ import annotations

import base64
import json

import numpy as np

__all__ = ["wrap", "assets", "encode"]

FLOAT16_MAX = 65504.0


def encode(image: np.ndarray) -> str:
    """``image`` (H, W, 3) as base64 little-endian float16 (finite values clipped to
    ±65504; NaN stays NaN, ±Inf stays ±Inf)."""
    a = np.asarray(image, dtype=np.float64)[..., :3]
    finite = np.isfinite(a)
    a = np.where(finite, np.clip(a, -FLOAT16_MAX, FLOAT16_MAX), a)
    return base64.b64encode(np.ascontiguousarray(a, dtype="<f2").tobytes()).decode("ascii")


def wrap(static_html: str, reference: np.ndarray, own: np.ndarray, *, exposure: float,
         err_eps: float, label: str = "own") -> str:
    """The static triplet ``static_html`` inside a viewer container with the data
    of ``reference`` and ``own`` (same (H, W, 3) shape; anything else returns
    ``static_html`` unchanged)."""
    if reference is None or own is None or reference.shape != own.shape or reference.ndim != 3:
        return static_html
    h, w = reference.shape[:2]
    data = {"w": int(w), "h": int(h), "exposure": float(exposure), "eps": float(err_eps),
            "label": str(label), "ref": encode(reference), "own": encode(own)}
    # JSON inside <script type="application/json"> is not executed; '</' is escaped so
    # no string can close the element.
    payload = json.dumps(data).replace("</", "<\\/")
    return (f'<div class="gbv">{static_html}'
            f'<script type="application/json" class="gbv-data">{payload}</script></div>')


def _inferno_lut() -> str:
    import matplotlib

    lut = (matplotlib.colormaps["inferno"](np.linspace(0.0, 1.0, 256))[:, :3] * 255).round()
    return base64.b64encode(lut.astype(np.uint8).tobytes()).decode("ascii")


CSS = """
.gbv-ui{margin:.3em 0}.gbv-bar{display:flex;flex-wrap:wrap;gap:.4em;align-items:center;font-size:12px;margin-bottom:.3em}
.gbv-bar button{font-size:12px;padding:.1em .6em;border:1px solid #bbb;background:#f6f6f6;border-radius:3px;cursor:pointer}
.gbv-bar button.on{background:#333;color:#fff;border-color:#333}
.gbv-view{max-width:100%;max-height:70vh;overflow:auto;background:#111;display:inline-block;position:relative}
.gbv-view canvas{display:block;image-rendering:pixelated;image-rendering:crisp-edges;cursor:crosshair}
.gbv-readout{font:12px ui-monospace,monospace;color:#333;min-height:1.4em;white-space:pre}
"""

JS = r"""
(function(){
const LUT=Uint8Array.from(atob("__LUT__"),c=>c.charCodeAt(0));
function halfs(b64){const s=atob(b64),n=s.length>>1,out=new Float32Array(n);
 for(let i=0;i<n;i++){const h=s.charCodeAt(2*i)|(s.charCodeAt(2*i+1)<<8),e=(h>>10)&31,m=h&1023,sg=h&32768?-1:1;
  out[i]=e===0?sg*m*5.960464477539063e-8:e===31?(m?NaN:sg*Infinity):sg*(1+m/1024)*Math.pow(2,e-15);}
 return out;}
function srgb(x){x=x>0?(x<1?x:1):0;return x<=0.0031308?12.92*x:1.055*Math.pow(x,1/2.4)-0.055;}
function fmt(v){return Number.isFinite(v)?(Math.abs(v)>=1e4||(v!==0&&Math.abs(v)<1e-3)?v.toExponential(3):v.toPrecision(4)):String(v);}
const MODES=["own","reference","error","split"];
function Viewer(box){
 const d=JSON.parse(box.querySelector("script.gbv-data").textContent);
 const W=d.w,H=d.h,own=halfs(d.own),ref=halfs(d.ref),err=new Float32Array(W*H);
 for(let i=0;i<W*H;i++){let s=0;for(let c=0;c<3;c++){const r=ref[3*i+c];s+=Math.abs(own[3*i+c]-r)/(Math.abs(r)+d.eps);}
  s/=3;err[i]=Number.isFinite(s)?s:1;}
 const st={mode:"own",stops:0,zoom:Math.max(1,Math.min(16,Math.floor(256/W)||1)),split:Math.floor(W/2),last:"reference"};
 const ui=document.createElement("div");ui.className="gbv-ui";
 ui.innerHTML='<div class="gbv-bar">'+MODES.map((m,k)=>'<button data-mode="'+m+'" title="key '+(k+1)+'">'+(m==="own"?d.label.replace(/[<&]/g,""):m)+'</button>').join("")
  +'<button data-flip="1" title="key f">flip</button>'
  +'<label>exposure <input class="gbv-exp" type="range" min="-10" max="10" step="0.5" value="0"> <span class="gbv-stops">+0 EV</span></label>'
  +'<button data-zoom="-1" title="key -">−</button><span class="gbv-zoom"></span><button data-zoom="1" title="key +">+</button>'
  +'<span class="gbv-mode"></span></div><div class="gbv-view"><canvas tabindex="0"></canvas></div><div class="gbv-readout">hover a pixel</div><div class="small">sRGB at the report\'s common exposure ×'+fmt(d.exposure)+' (reference 99th percentile → white) × 2^EV; error: |own − ref| / (|ref| + '+d.eps+'), mean over channels, inferno on [0, 1]; values are the displayed pixels in half precision. Keys: 1-4 modes, f flip, +/− zoom.</div>';
 const cv=ui.querySelector("canvas"),ctx=cv.getContext("2d"),img=ctx.createImageData(W,H);cv.width=W;cv.height=H;
 const readout=ui.querySelector(".gbv-readout");
 function draw(){
  const k=d.exposure*Math.pow(2,st.stops),px=img.data;
  for(let y=0;y<H;y++)for(let x=0;x<W;x++){const i=y*W+x,o=4*i;
   let m=st.mode;if(m==="split")m=x<st.split?"own":"reference";
   if(m==="error"){const l=3*Math.max(0,Math.min(255,Math.round(err[i]*255)));px[o]=LUT[l];px[o+1]=LUT[l+1];px[o+2]=LUT[l+2];}
   else{const a=m==="own"?own:ref;for(let c=0;c<3;c++){const v=a[3*i+c];px[o+c]=Number.isFinite(v)?Math.round(255*srgb(v*k)):255;}}
   px[o+3]=255;}
  if(st.mode==="split")for(let y=0;y<H;y++){const o=4*(y*W+Math.min(W-1,st.split));px[o]=255;px[o+1]=255;px[o+2]=255;}
  ctx.putImageData(img,0,0);
  cv.style.width=(W*st.zoom)+"px";cv.style.height=(H*st.zoom)+"px";
  ui.querySelector(".gbv-zoom").textContent="×"+st.zoom;
  ui.querySelector(".gbv-stops").textContent=(st.stops>=0?"+":"")+st.stops+" EV";
  ui.querySelector(".gbv-mode").textContent=st.mode;
  ui.querySelectorAll("button[data-mode]").forEach(b=>b.classList.toggle("on",b.dataset.mode===st.mode));
  box.dataset.mode=st.mode;box.dataset.zoom=st.zoom;box.dataset.stops=st.stops;}
 function set(mode){if(mode==="own"||mode==="reference")st.last=st.mode==="own"||st.mode==="reference"?st.mode:st.last;st.mode=mode;draw();}
 function flip(){set(st.mode==="own"?"reference":st.mode==="reference"?"own":st.last==="own"?"reference":"own");}
 function zoom(dz){st.zoom=Math.max(1,Math.min(16,dz>0?st.zoom*2:Math.floor(st.zoom/2)));draw();}
 ui.addEventListener("click",e=>{const b=e.target.closest("button");if(!b)return;
  if(b.dataset.mode)set(b.dataset.mode);else if(b.dataset.flip)flip();else if(b.dataset.zoom)zoom(+b.dataset.zoom);});
 ui.querySelector(".gbv-exp").addEventListener("input",e=>{st.stops=+e.target.value;draw();});
 cv.addEventListener("mousemove",e=>{const r=cv.getBoundingClientRect();
  const x=Math.floor((e.clientX-r.left)/r.width*W),y=Math.floor((e.clientY-r.top)/r.height*H);
  if(x<0||y<0||x>=W||y>=H)return;const i=y*W+x;
  if(st.mode==="split"){st.split=x;draw();}
  const v=a=>"("+[0,1,2].map(c=>fmt(a[3*i+c])).join(", ")+")";
  readout.textContent="x "+x+", y "+y+"   own "+v(own)+"   ref "+v(ref)+"   rel. error "+fmt(err[i]);
  box.dataset.pixel=x+","+y;});
 cv.addEventListener("keydown",e=>{const k=MODES[+e.key-1];if(k)set(k);else if(e.key==="f")flip();
  else if(e.key==="+"||e.key==="=")zoom(1);else if(e.key==="-")zoom(-1);else return;e.preventDefault();});
 box.querySelector(".images").style.display="none";
 box.insertBefore(ui,box.firstChild);box.classList.add("gbv-live");draw();
 box.gbv={set,flip,zoom,exposure:s=>{st.stops=s;ui.querySelector(".gbv-exp").value=s;draw();},canvas:cv};}
document.querySelectorAll(".gbv").forEach(b=>{try{Viewer(b);}catch(e){b.dataset.gbvError=String(e);}});
})();
"""


def assets() -> str:
    """The viewer's CSS and script, once per page (place at the end of ``<body>``)."""
    return f"<style>{CSS}</style><script>{JS.replace('__LUT__', _inferno_lut())}</script>"
