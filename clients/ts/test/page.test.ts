import { test } from "node:test";
import assert from "node:assert/strict";
import { bundle, committed, OUT } from "../page/bundle.js";

test("the gateway's play page script is the bundle of page/play.ts as it stands", async () => {
  const fresh = await bundle();
  assert.ok(fresh.includes("fire_ray") && fresh.includes("decodeServer"), "the page and the package are in it");
  assert.ok(fresh === committed(), `${OUT} is behind its sources: run npm run page in clients/ts and commit it`);
});
