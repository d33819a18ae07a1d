import { defineConfig } from 'vite';

// Fixed file names: the binary embeds dist/index.html, dist/assets/app.js and dist/worklet.js by name
// (tools/serve/src/web.rs), so a rebuild only changes their contents.
export default defineConfig({
  // relative URLs: the same build is served by `livegesture serve` at / and as a static folder at any path
  base: './',
  build: {
    outDir: 'dist',
    emptyOutDir: true,
    assetsInlineLimit: 0,
    chunkSizeWarningLimit: 850, // three.js is most of app.js
    modulePreload: { polyfill: false },
    rollupOptions: {
      output: {
        entryFileNames: 'assets/app.js',
        chunkFileNames: 'assets/[name].js',
        assetFileNames: 'assets/[name][extname]',
        inlineDynamicImports: true,
      },
    },
  },
});
