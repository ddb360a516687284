// The console is served by the station at `/`; build.rs passes --outDir (cargo's OUT_DIR).
// `npm run dev` serves it with hot reload and forwards the API to a running `shoal up`.
import { defineConfig } from 'vite';

export default defineConfig({
  base: '/',
  build: {
    target: 'es2022',
    // OpenLayers is most of the bundle; one chunk loads faster over loopback than many.
    chunkSizeWarningLimit: 2000,
    sourcemap: false,
  },
  server: {
    host: '127.0.0.1',
    proxy: {
      '/api': { target: 'http://127.0.0.1:8640', ws: true },
      '/status.html': 'http://127.0.0.1:8640',
    },
  },
});
