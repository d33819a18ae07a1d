// The face panel: what a person can read of the face, the mouth opening (the jaw's rotation) as a
// number and as a strip chart of the last seconds. The 100 expression coefficients stay available as
// data: in a collapsed list, and in window.lgState.expressions (the latest frame's 100 values).
import { jawOpening, JAW_OPEN_FULL } from './retarget.js';

const SECONDS = 8;
const FPS = 30;

export function createFacePanel(box, state) {
  box.innerHTML = `
    <div class="row"><span class="k">mouth opening</span><span id="mouthv">0%</span></div>
    <canvas id="mouthChart" width="272" height="70" style="width:100%;height:70px;background:#15181d;border-radius:4px"></canvas>
    <small>last ${SECONDS} s; 100% = jaw open ${(JAW_OPEN_FULL * 180 / Math.PI).toFixed(0)}&deg;</small>
    <details id="exprData"><summary class="k">expression coefficients (100, data)</summary>
      <pre id="exprList" style="font-size:10px;line-height:1.25;white-space:pre-wrap;margin:4px 0"></pre></details>`;
  const canvas = box.querySelector('#mouthChart');
  const g = canvas.getContext('2d');
  const value = box.querySelector('#mouthv');
  const details = box.querySelector('#exprData');
  const list = box.querySelector('#exprList');
  const n = SECONDS * FPS;
  const hist = new Float32Array(n);
  let count = 0, lastIndex = -1, lastList = 0;

  function draw() {
    const w = canvas.width, h = canvas.height;
    g.clearRect(0, 0, w, h);
    g.strokeStyle = '#2a2e36'; g.lineWidth = 1;
    for (const f of [0.25, 0.5, 0.75]) { g.beginPath(); g.moveTo(0, h * f); g.lineTo(w, h * f); g.stroke(); }
    const k = Math.min(count, n);
    if (k < 2) return;
    g.beginPath();
    for (let i = 0; i < k; i++) {
      const v = hist[(count - k + i) % n];
      const x = w - (k - 1 - i) * (w / (n - 1));
      const y = h - 2 - Math.min(1, Math.max(0, v)) * (h - 4);
      if (i === 0) g.moveTo(x, y); else g.lineTo(x, y);
    }
    g.strokeStyle = '#f0a030'; g.lineWidth = 1.5; g.stroke();
  }

  return {
    reset() { count = 0; lastIndex = -1; draw(); },
    // one frame: { index, poses, expressions }
    update(f) {
      const open = Math.max(0, jawOpening(f.poses)) / JAW_OPEN_FULL;
      if (f.index !== lastIndex + 1) count = 0; // a new motion or a jump in a played file
      lastIndex = f.index;
      hist[count % n] = open;
      count++;
      value.textContent = `${Math.round(Math.min(1, open) * 100)}%`;
      state.mouthOpening = open;
      state.expressions = Array.from(f.expressions);
      draw();
      const now = performance.now();
      if (details.open && now - lastList > 100) {
        lastList = now;
        list.textContent = state.expressions.map((v, i) => `${String(i).padStart(2)}:${v.toFixed(2).padStart(5)}`).join(' ');
      }
    },
  };
}
