// The trainer page (/train/PACK): draws the pictures the server streams over the WebSocket and sends
// the mouse, wheel and keyboard back as the trainer's input events (game/server/train_routes.py).
// Coordinates go in window units with the origin at the bottom-left, as the desktop window gives them.
"use strict";
(function () {
  const canvas = document.getElementById("train-screen");
  const state = document.getElementById("train-state");
  const g = canvas.getContext("2d");
  let W = canvas.width, H = canvas.height, mime = "image/jpeg";
  // figures the benchmark reads (chainsim bench train): frames, bytes, input-to-picture latencies
  const stats = (window.trainStats = { frames: 0, bytes: 0, shownSeq: 0, latencies: [], ready: false, closed: null });
  const sentAt = new Map(); // seq of a key or button press -> when it was sent (ms)
  let seq = 0, ws = null, drawing = Promise.resolve();

  function fit() {
    // pixel for pixel when the browser window is wide and tall enough (centred in it, wider than the
    // page's column), else scaled down to fit, keeping its shape
    const width = Math.max(320, Math.floor(Math.min(W, window.innerWidth - 24, (window.innerHeight - 24) * (W / H))));
    canvas.style.maxWidth = "none"; // the stylesheet keeps canvases in the column; this one may be wider
    canvas.style.width = width + "px";
    canvas.style.height = Math.round((width * H) / W) + "px";
    canvas.style.marginLeft = "0px";
    const left = canvas.getBoundingClientRect().left;
    canvas.style.marginLeft = Math.round((window.innerWidth - width) / 2 - left) + "px";
  }
  window.addEventListener("resize", fit);
  fit();

  function say(text, bad) {
    state.textContent = text;
    state.className = bad ? "error" : "note";
  }

  function send(msg, probe) {
    if (!ws || ws.readyState !== WebSocket.OPEN) return;
    if (msg.type !== "ack") {
      msg.seq = ++seq;
      if (probe) sentAt.set(seq, performance.now());
    }
    ws.send(JSON.stringify(msg));
  }

  // past this median of the last few input-to-picture times the page says the link or server is slow, in
  // a box over the page's corner (fixed: a line added above the picture would move it under the pointer)
  const HIGH_LATENCY_MS = 300;
  const slow = document.createElement("div");
  slow.id = "train-latency";
  slow.className = "error";
  slow.setAttribute("role", "status");
  Object.assign(slow.style, {
    position: "fixed", top: "8px", right: "8px", maxWidth: "28em", padding: "6px 10px", zIndex: 10,
    background: "#fff3f0", border: "1px solid #c0392b", borderRadius: "4px", font: "14px sans-serif",
  });
  slow.hidden = true;
  document.body.appendChild(slow);

  function latencyNotice() {
    const recent = stats.latencies.slice(-7).sort((a, b) => a - b);
    if (recent.length < 3) return;
    const median = recent[recent.length >> 1];
    slow.hidden = median <= HIGH_LATENCY_MS;
    if (!slow.hidden) {
      slow.textContent = "High latency: about " + Math.round(median) + " ms from your input to the picture " +
        "(the network or the server is slow); the pictures' quality drops to keep up.";
    }
  }

  function shown(data) {
    // one frame: the parts of the picture that changed (game/server/frame_tiles.py: the wire format)
    const head = new DataView(data);
    const frameSeq = head.getUint32(4), n = head.getUint16(8);
    const runs = [];
    let at = 10;
    for (let i = 0; i < n; i++) {
      const x = head.getUint16(at), y = head.getUint16(at + 2), len = head.getUint32(at + 8);
      runs.push([x, y, new Blob([data.slice(at + 12, at + 12 + len)], { type: mime })]);
      at += 12 + len;
    }
    drawing = drawing.then(async () => {
      const bitmaps = await Promise.all(runs.map((r) => createImageBitmap(r[2])));
      bitmaps.forEach((bitmap, i) => { g.drawImage(bitmap, runs[i][0], runs[i][1]); bitmap.close(); });
      const now = performance.now();
      for (const [s, t] of sentAt) {
        if (s <= frameSeq) {
          stats.latencies.push(now - t);
          if (stats.latencies.length > 10000) stats.latencies.splice(0, 5000); // a long session keeps the newest
          sentAt.delete(s);
        }
      }
      stats.frames += 1;
      stats.shownSeq = frameSeq;
      latencyNotice();
      send({ type: "ack" }); // drawn: the server may send the next picture
    }).catch(() => send({ type: "ack" }));
  }

  const fresh = document.getElementById("train-fresh");
  fresh.addEventListener("click", () => {
    // end the resumed session on the server and start a new one (its attempt in progress is not saved)
    fresh.hidden = true;
    if (ws) { ws.onclose = null; ws.close(); }
    connect(true);
  });

  function connect(afresh) {
    const scheme = location.protocol === "https:" ? "wss:" : "ws:";
    ws = new WebSocket(scheme + "//" + location.host + canvas.dataset.socket + (afresh ? (canvas.dataset.socket.includes("?") ? "&" : "?") + "fresh=1" : ""));
    ws.binaryType = "arraybuffer";
    say("Starting the trainer on the server...");
    ws.onmessage = (e) => {
      if (typeof e.data === "string") {
        const msg = JSON.parse(e.data);
        if (msg.type === "starting") say("Starting the trainer on the server (a few seconds)...");
        if (msg.type === "ready") {
          W = canvas.width = msg.width;
          H = canvas.height = msg.height;
          mime = msg.format;
          fit();
          stats.ready = true;
          if (msg.resumed) {
            // a reload (or another tab) came back to the session that was running: say so, and offer a new one
            const mins = Math.round(msg.age_s / 60);
            say("Resumed your session from " + (mins >= 1 ? mins + " min" : msg.age_s + " s") +
                " ago: the attempt in progress goes on where you left it. Click the picture to give it the keyboard.");
            fresh.hidden = false;
          } else {
            say("Trainer ready: click the picture to give it the keyboard.");
            fresh.hidden = true;
          }
          canvas.focus();
        }
        return;
      }
      stats.bytes += e.data.byteLength;
      shown(e.data);
    };
    ws.onclose = (e) => {
      stats.closed = { code: e.code, reason: e.reason };
      const why = e.reason || "the connection to the server was lost";
      say("The trainer stopped: " + why + ". Reload the page to start again.", true);
    };
  }

  // -- mouse and wheel ------------------------------------------------------------------------
  let buttons = 0, last = null, pendingMove = null;
  const BUTTON = ["left", "middle", "right"];

  function at(e) {
    const r = canvas.getBoundingClientRect();
    // whole window units, as a desktop window reports the pointer
    const x = Math.round(((e.clientX - r.left) * W) / r.width);
    const y = Math.round(H - ((e.clientY - r.top) * H) / r.height);
    return [Math.min(Math.max(x, 0), W), Math.min(Math.max(y, 0), H)];
  }
  function flush() {
    if (pendingMove) send(pendingMove);
    pendingMove = null;
  }
  canvas.addEventListener("mousemove", (e) => {
    const [x, y] = at(e);
    if (buttons) {
      const held = BUTTON[[1, 4, 2].findIndex((b) => buttons & b)] || "left";
      const dx = last ? x - last[0] : 0, dy = last ? y - last[1] : 0;
      // moves within one animation frame become one drag with their summed motion
      if (pendingMove && pendingMove.type === "mouse_drag") {
        pendingMove.x = x; pendingMove.y = y; pendingMove.dx += dx; pendingMove.dy += dy;
      } else {
        flush();
        pendingMove = { type: "mouse_drag", x, y, dx, dy, button: held };
      }
    } else {
      pendingMove = { type: "mouse_move", x, y };
    }
    last = [x, y];
    requestAnimationFrame(flush);
  });
  canvas.addEventListener("mousedown", (e) => {
    canvas.focus();
    e.preventDefault();
    flush();
    const [x, y] = at(e);
    buttons = e.buttons;
    last = [x, y];
    send({ type: "mouse_button", x, y, button: BUTTON[e.button] || "left", pressed: true }, true);
  });
  window.addEventListener("mouseup", (e) => {
    if (!buttons) return;
    flush();
    const [x, y] = at(e);
    buttons = e.buttons;
    send({ type: "mouse_button", x, y, button: BUTTON[e.button] || "left", pressed: false });
  });
  canvas.addEventListener("contextmenu", (e) => e.preventDefault()); // right-drag is the X-ray's contrast
  canvas.addEventListener("wheel", (e) => {
    e.preventDefault();
    const [x, y] = at(e);
    const notches = e.deltaMode === 0 ? e.deltaY / 100 : e.deltaMode === 1 ? e.deltaY / 3 : e.deltaY;
    send({ type: "scroll", x, y, dy: Math.max(-10, Math.min(10, -notches)) });
  }, { passive: false });

  // -- keyboard: the browser's key names to the trainer's (pyglet's) ----------------------------
  const NAMED = {
    ArrowLeft: "left", ArrowRight: "right", ArrowUp: "up", ArrowDown: "down", " ": "space",
    Escape: "escape", Home: "home", End: "end", PageUp: "pageup", PageDown: "pagedown", Enter: "return",
    Backspace: "backspace", Delete: "delete", Insert: "insert", "-": "minus", "=": "equal",
    ",": "comma", ".": "period", "/": "slash", ";": "semicolon", "'": "apostrophe", "[": "bracketleft",
    "]": "bracketright", "\\": "backslash", "`": "grave",
  };
  function keyName(e) {
    if (e.key === "Shift" || e.key === "Control" || e.key === "Alt") {
      return (e.code.endsWith("Right") ? "r" : "l") + { Shift: "shift", Control: "ctrl", Alt: "alt" }[e.key];
    }
    // F12 stays the browser's (its tools), Tab too (the keyboard can leave the picture)
    if (/^F([1-9]|1[01])$/.test(e.key)) return e.key.toLowerCase();
    if (NAMED[e.key]) return NAMED[e.key];
    if (/^Key[A-Z]$/.test(e.code)) return e.code.slice(3).toLowerCase(); // letters by position, Shift or not
    if (/^Digit[0-9]$/.test(e.code)) return e.code.slice(5);
    return null;
  }
  canvas.addEventListener("keydown", (e) => {
    const name = keyName(e);
    if (!name || e.ctrlKey || e.metaKey) return; // browser shortcuts (Ctrl+R, Ctrl+W) stay the browser's
    e.preventDefault();
    flush();
    send({ type: "key", key: name, pressed: true }, !e.repeat);
  });
  canvas.addEventListener("keyup", (e) => {
    const name = keyName(e);
    if (!name) return;
    e.preventDefault();
    send({ type: "key", key: name, pressed: false });
  });

  connect();
})();
