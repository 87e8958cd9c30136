// The part of uPlot (vendored: src/kybercore/web/vendor/uPlot.iife.min.js, 1.6.32) that
// charts.js uses. The script defines a global `uPlot`; charts.js loads it on first use.

/** A drawn chart. */
interface UPlotChart {
  readonly width: number;
  readonly height: number;
  setSize(size: { width: number; height: number }): void;
  setData(data: (number | null)[][]): void;
  destroy(): void;
}

/** The uPlot constructor and its path builders. */
interface UPlotStatic {
  new (options: object, data: (number | null)[][], target: HTMLElement): UPlotChart;
  paths: { bars(options: { size?: [number, number]; align?: -1 | 0 | 1 }): unknown };
}

interface Window {
  uPlot?: UPlotStatic;
}
